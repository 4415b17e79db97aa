"""Reference trajectories for the formation centre, p_c^d(t).

The paper's reference was only in its lost Fig. 3, so the project offers a
family: a path flown at constant speed whose turn rate is piecewise constant
(straight legs and circular arcs). Position and heading are closed-form, so
the reference costs nothing to evaluate and has no integration error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ReferencePath:
    """Constant-speed path of straight legs and circular arcs."""

    name: str
    """Name used in scenarios and results."""
    heading: float = 0.0
    """Heading at t = 0, in radians (0 = +x, counter-clockwise positive)."""
    speed: float = 15.0
    """Speed along the path, m/s, > 0."""
    segments: tuple[tuple[float, float], ...] = ()
    """``(duration_s, turn_rate_rad_s)`` pieces flown in order; after the last
    piece the path continues straight. Durations > 0."""

    def __post_init__(self) -> None:
        if not (self.speed > 0 and math.isfinite(self.speed)):
            raise ValueError(f"ReferencePath.speed must be a finite number > 0, got {self.speed}")
        if not math.isfinite(self.heading):
            raise ValueError(f"ReferencePath.heading must be finite, got {self.heading}")
        for i, seg in enumerate(self.segments):
            if (
                len(seg) != 2
                or not (seg[0] > 0 and math.isfinite(seg[0]))
                or not math.isfinite(seg[1])
            ):
                raise ValueError(
                    f"ReferencePath.segments[{i}] must be (duration > 0, finite turn rate), "
                    f"got {seg}"
                )

    def _knots(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Start time, position, heading and turn rate of every piece."""
        pieces = [*self.segments, (math.inf, 0.0)]
        times, xs, ys, headings, rates = [], [], [], [], []
        t, x, y, psi = 0.0, 0.0, 0.0, float(self.heading)
        for duration, rate in pieces:
            times.append(t)
            xs.append(x)
            ys.append(y)
            headings.append(psi)
            rates.append(rate)
            if math.isinf(duration):
                break
            dx, dy = _advance(self.speed, psi, rate, duration)
            x, y, psi, t = x + dx, y + dy, psi + rate * duration, t + duration
        return (np.array(times), np.array(xs), np.array(ys), np.array(headings), np.array(rates))

    def evaluate(
        self, t: np.ndarray, start: tuple[float, float] = (0.0, 0.0)
    ) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(len(t), 2)`` and headings ``(len(t),)`` at times ``t`` (s).

        The path starts at ``start`` at t = 0.
        """
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        times, xs, ys, headings, rates = self._knots()
        piece = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1)
        tau = t - times[piece]
        psi0 = headings[piece]
        rate = rates[piece]
        dx, dy = _advance(self.speed, psi0, rate, tau)
        positions = np.column_stack((start[0] + xs[piece] + dx, start[1] + ys[piece] + dy))
        return positions, psi0 + rate * tau

    def position(self, t: np.ndarray, start: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Positions ``(len(t), 2)`` at times ``t``."""
        return self.evaluate(t, start)[0]


def _advance(speed: float, heading, rate, duration):
    """Displacement after flying ``duration`` at ``speed`` from ``heading`` turning at ``rate``.

    Uses the sinc form so that a zero or tiny turn rate is exact, not 0/0.
    """
    heading = np.asarray(heading, dtype=np.float64)
    rate = np.asarray(rate, dtype=np.float64)
    duration = np.asarray(duration, dtype=np.float64)
    half_turn = 0.5 * rate * duration
    # sin(r d / 2) / (r / 2) == d * sinc(r d / (2 pi)); numpy's sinc is sin(pi x)/(pi x).
    chord = speed * duration * np.sinc(half_turn / np.pi)
    mid_heading = heading + half_turn
    return chord * np.cos(mid_heading), chord * np.sin(mid_heading)


REFERENCE_PATHS: dict[str, ReferencePath] = {
    path.name: path
    for path in (
        ReferencePath(name="straight"),
        # 15 s straight, a 90 degree left turn of radius 191 m over 20 s, then straight.
        ReferencePath(name="turn", segments=((15.0, 0.0), (20.0, math.pi / 40.0))),
        # Left then right: two 60 degree arcs of radius 215 m, 15 s each.
        ReferencePath(
            name="s-curve",
            segments=((12.0, 0.0), (15.0, math.pi / 45.0), (15.0, -math.pi / 45.0)),
        ),
    )
}
