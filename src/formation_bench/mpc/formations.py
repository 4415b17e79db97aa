"""Formation shapes for any number of UAVs, and seeded initial states around them.

A shape gives every UAV's offset from the formation centre in the path frame (x forward,
y left), with zero mean, neighbouring slots ``spacing_m`` apart.
:func:`~formation_bench.mpc.scenario.swarm_scenario` turns a shape into a scenario with
explicit initial states, drawn once from a documented, seeded distribution around the start
of the reference (:func:`scattered_initial_states`), so a registered swarm is plain data:
every run of it starts from the same states, whatever the run's seed.
"""

from __future__ import annotations

import enum
import math

import numpy as np


class FormationShape(enum.StrEnum):
    """The formation library."""

    TRIANGLE = "triangle"
    """The paper's isosceles right triangle (3 UAVs only): two abreast in front ``2 * spacing``
    apart, one trailing at the right angle."""
    LINE_ABREAST = "line-abreast"
    """One line across the path."""
    ECHELON = "echelon"
    """One diagonal line, each UAV behind and to the right of the one before."""
    WEDGE = "wedge"
    """A V: a leader in front, the others alternately behind-left and behind-right."""
    DIAMOND = "diamond"
    """The grid turned by 45 degrees (4 UAVs: front, left, right, rear)."""
    CIRCLE = "circle"
    """Evenly around a circle, neighbours ``spacing`` apart along the chord."""
    GRID = "grid"
    """Rows of ``ceil(sqrt(N))`` across the path, filled from the front."""


def _grid(n_uav: int, spacing: float) -> np.ndarray:
    columns = math.ceil(math.sqrt(n_uav))
    slots = np.arange(n_uav)
    rows, cols = slots // columns, slots % columns
    return np.stack((-rows * spacing, (cols - (columns - 1) / 2) * spacing), axis=1)


def formation_offsets(shape: FormationShape | str, n_uav: int, spacing_m: float) -> np.ndarray:
    """Offsets ``(n_uav, 2)`` of ``shape`` from the formation centre, zero mean, path frame."""
    shape = FormationShape(shape)
    if not (isinstance(n_uav, int) and n_uav >= 2):
        raise ValueError(f"n_uav must be an integer >= 2, got {n_uav!r}")
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise ValueError(f"spacing_m must be a finite number > 0, got {spacing_m!r}")
    s = float(spacing_m)
    k = np.arange(n_uav, dtype=np.float64)
    if shape == FormationShape.TRIANGLE:
        if n_uav != 3:
            raise ValueError(f"the triangle formation has 3 UAVs, got n_uav={n_uav}")
        points = np.array([[0.0, -s], [-s, 0.0], [0.0, s]])
    elif shape == FormationShape.LINE_ABREAST:
        points = np.stack((np.zeros(n_uav), -k * s), axis=1)
    elif shape == FormationShape.ECHELON:
        points = np.stack((-k * s / math.sqrt(2), -k * s / math.sqrt(2)), axis=1)
    elif shape == FormationShape.WEDGE:
        rank = (k + 1) // 2  # 0, 1, 1, 2, 2, ...
        side = np.where(k % 2 == 1, 1.0, -1.0)
        points = np.stack((-rank * s / math.sqrt(2), side * rank * s / math.sqrt(2)), axis=1)
    elif shape == FormationShape.DIAMOND:
        grid = _grid(n_uav, s)
        grid -= grid.mean(axis=0)
        c = math.sqrt(0.5)
        points = np.stack((c * (grid[:, 0] - grid[:, 1]), c * (grid[:, 0] + grid[:, 1])), axis=1)
    elif shape == FormationShape.CIRCLE:
        radius = s / (2.0 * math.sin(math.pi / n_uav))
        angle = 2.0 * math.pi * k / n_uav
        points = np.stack((radius * np.cos(angle), radius * np.sin(angle)), axis=1)
    else:
        points = _grid(n_uav, s)
    return points - points.mean(axis=0)


def scattered_initial_states(
    offsets: np.ndarray,
    rng: np.random.Generator,
    *,
    start: tuple[float, float] = (0.0, 0.0),
    heading: float = 0.0,
    spread: float = 1.5,
    jitter_m: float | None = None,
    heading_std_rad: float = 0.3,
    speed_range_m_s: tuple[float, float] = (13.0, 17.0),
) -> np.ndarray:
    """Initial states ``(N, 4)`` scattered around the formation's slots at the reference start.

    Each UAV starts at ``start`` + its offset scaled by ``spread`` and turned to ``heading``,
    moved by a normal draw of standard deviation ``jitter_m`` per axis (default: a third of
    the smallest slot gap); the draw is repeated until every pair is at least half the
    smallest slot gap apart. Headings are ``heading`` plus a normal of ``heading_std_rad``,
    speeds uniform over ``speed_range_m_s``.
    """
    offsets = np.asarray(offsets, dtype=np.float64)
    n_uav = offsets.shape[0]
    gaps = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1)
    min_gap = float(gaps[np.triu_indices(n_uav, k=1)].min())
    jitter = min_gap / 3.0 if jitter_m is None else jitter_m
    cos, sin = math.cos(heading), math.sin(heading)
    turned = spread * np.stack(
        (cos * offsets[:, 0] - sin * offsets[:, 1], sin * offsets[:, 0] + cos * offsets[:, 1]),
        axis=1,
    )
    for _ in range(1000):
        positions = np.asarray(start) + turned + rng.normal(0.0, jitter, size=(n_uav, 2))
        apart = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
        if apart[np.triu_indices(n_uav, k=1)].min() >= min_gap / 2:
            break
    else:  # pragma: no cover - needs a jitter far above the gaps
        raise ValueError("could not draw initial positions half a slot gap apart; lower jitter_m")
    headings = heading + rng.normal(0.0, heading_std_rad, size=n_uav)
    speeds = rng.uniform(*speed_range_m_s, size=n_uav)
    return np.column_stack((positions, headings, speeds))
