"""Scenarios: everything the DMPC harness needs, as one validated dataclass.

The default is the paper's Section 3 scenario; the choices the paper leaves
open (reference path, formation frame, estimate extension, decision blocking,
weights) are fields with documented defaults, so a sweep can vary them.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.fields import setting, validate_fields
from formation_bench.mpc.reference import REFERENCE_PATHS, ReferencePath
from formation_bench.plugins import SCENARIO_GROUP, Registry


class FormationFrame(enum.StrEnum):
    """Frame in which the formation offsets are fixed."""

    PATH = "path"
    """Offsets turn with the reference path's heading (x forward, y left)."""
    WORLD = "world"
    """Offsets are fixed in the world frame."""


class EstimateExtension(enum.StrEnum):
    """How a neighbour's estimate is extended past the end of its last plan."""

    COAST = "coast"
    """Propagate the plan's terminal state with zero control (constant speed and heading)."""
    HOLD = "hold"
    """Hold the plan's terminal position (the literal reading of Section 2.2)."""


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


def _number_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float array, or a ValueError naming the field."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"Scenario.{name} must be a tuple of tuples of numbers, got {value!r}"
        ) from None


@dataclass(frozen=True)
class Scenario:
    """A formation-control scenario and the DMPC settings that go with it."""

    name: str = setting("paper", allowed="any string", doc="Name used in results")
    initial_states: tuple[tuple[float, float, float, float], ...] = setting(
        (
            (-7.08, -17.96, math.radians(68.02), 13.12),
            (-18.48, -5.25, math.radians(14.74), 15.43),
            (-15.46, 11.29, math.radians(-35.97), 16.83),
        ),
        allowed="at least 2 finite (x, y, heading, speed) tuples",
        doc="Initial (x m, y m, heading rad, speed m/s) of every UAV (Table 1)",
    )
    formation_offsets: tuple[tuple[float, float], ...] = setting(
        ((10.0 / 3.0, -10.0), (-20.0 / 3.0, 0.0), (10.0 / 3.0, 10.0)),
        allowed="one (x, y) per UAV, zero mean",
        doc="Desired position of every UAV relative to the formation centre, m, in formation_frame",
    )
    """Their mean must be zero (the centre is the UAVs' mean). The default is the paper's
    isosceles right triangle: hypotenuse 20 m between UAV 1 and UAV 3 across the path, UAV 2 at
    the right angle trailing."""
    formation_frame: FormationFrame = setting(
        FormationFrame.PATH,
        doc="Frame of the offsets: turning with the reference heading, or fixed in the world",
    )
    reference: str = setting(
        "turn",
        choices=lambda: sorted(REFERENCE_PATHS),
        doc="Reference path of the formation centre: one of REFERENCE_PATHS",
    )
    reference_start: tuple[float, float] | None = setting(
        None,
        optional=True,
        allowed="two finite numbers",
        doc="Where the reference path starts at t = 0, m; None = the UAVs' initial centre",
    )
    """None means the UAVs' mean initial position."""
    period_s: float = setting(
        0.2, low=0.0, low_open=True, doc="Control update period delta_T, seconds"
    )
    horizon_steps: int = setting(
        20, low=1, high=10_000, doc="Prediction horizon in periods (Tp = horizon_steps * period_s)"
    )
    n_steps: int = setting(240, low=1, high=10_000_000, doc="Update instants simulated")
    accel_bounds: tuple[float, float] = setting(
        (-7.0, 7.0), allowed="finite (lower, upper), lower < upper",
        doc="Bounds on the acceleration a, m/s^2",
    )  # fmt: skip
    turn_rate_bounds: tuple[float, float] = setting(
        (-0.25, 0.25), allowed="finite (lower, upper), lower < upper",
        doc="Bounds on the turn rate omega, rad/s",
    )  # fmt: skip
    w_dst: float = setting(
        1.0, low=0.0, doc="Weight of the relative-position (formation) term of eq. (14)"
    )
    w_trj: float = setting(
        3.0, low=0.0, doc="Weight of the formation-centre tracking term of eq. (14)"
    )
    """The default 3 (with w_dst = 1) was chosen by measurement: see docs/design.md."""
    n_blocks: int = setting(
        5, low=1, high="horizon_steps",
        doc="Control blocks per horizon: the decision vector holds 2 * n_blocks numbers",
    )  # fmt: skip
    """Each control is held over ``horizon_steps / n_blocks`` periods. The default 5 (d = 10)
    was chosen by measurement: see docs/design.md."""
    estimate_extension: EstimateExtension = setting(
        EstimateExtension.COAST,
        doc="How neighbour estimates are extended past the end of their last plan",
    )
    eps_p: float = setting(
        2.0, low=0.0,
        doc="Trigger threshold on the predicted relative-position error, eq. (15), metres",
    )  # fmt: skip
    eps_o: float = setting(
        2.0, low=0.0,
        doc="Trigger threshold on the formation-centre tracking error, eq. (16), metres",
    )  # fmt: skip
    eta: float = setting(
        1.0, low=0.0, high=1.0, low_open=True,
        doc="Trigger fraction of the control bound, eq. (17)",
    )  # fmt: skip
    trigger_lookahead_steps: int | None = setting(
        None, kind=int, optional=True, low=0, high="horizon_steps",
        doc="Periods after t_c at which conditions (15)-(16) are checked; None = whole horizon",
    )  # fmt: skip
    """Conditions (15)-(16) are checked on the predicted trajectories at t_c and this many
    periods after it: None (the default) = the whole horizon, reading eq. (16)'s ``t`` as any
    predicted time; 0 checks t_c only."""
    settle_time_s: float = setting(
        10.0, low=0.0,
        doc="Metrics of tracking and formation error count from this time on, seconds",
    )  # fmt: skip
    rk4_substeps: int = setting(
        1, low=1, high=1000, doc="RK4 sub-steps per control period in prediction and plant"
    )
    settling_distance_band: float = setting(
        0.02, low=0.0, low_open=True,
        doc="Settling time: every pair's distance error within this fraction of its desired "
        "distance",
    )  # fmt: skip
    settling_tracking_band_m: float = setting(
        1.0, low=0.0, low_open=True,
        doc="Settling time: the formation centre within this distance of the reference, m",
    )  # fmt: skip

    def __post_init__(self) -> None:
        validate_fields(self)
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Scenario.name must be a non-empty string, got {self.name!r}")
        # the structured fields are checked together, after the declared ranges
        states = _number_array("initial_states", self.initial_states)
        offsets = _number_array("formation_offsets", self.formation_offsets)
        if states.ndim != 2 or states.shape[1] != 4 or states.shape[0] < 2:
            raise ValueError(
                "Scenario.initial_states must be a list of at least 2 (x, y, heading, speed) "
                f"tuples, got shape {states.shape}"
            )
        if not np.all(np.isfinite(states)):
            raise ValueError("Scenario.initial_states must be finite")
        if offsets.shape != (states.shape[0], 2):
            raise ValueError(
                f"Scenario.formation_offsets must hold one (x, y) per UAV "
                f"({states.shape[0]}), got shape {offsets.shape}"
            )
        if not np.allclose(offsets.mean(axis=0), 0.0, atol=1e-9):
            raise ValueError(
                "Scenario.formation_offsets must have zero mean (offsets are relative to the "
                f"formation centre), got mean {offsets.mean(axis=0).tolist()}"
            )
        if self.reference_start is not None and (
            not isinstance(self.reference_start, tuple | list)
            or len(self.reference_start) != 2
            or not all(_is_number(c) for c in self.reference_start)
            or not all(math.isfinite(c) for c in self.reference_start)
        ):
            raise ValueError(
                f"Scenario.reference_start must be None or two finite numbers, "
                f"got {self.reference_start!r}"
            )
        for field_name in ("accel_bounds", "turn_rate_bounds"):
            pair = getattr(self, field_name)
            if not (
                isinstance(pair, tuple | list)
                and len(pair) == 2
                and all(_is_number(v) for v in pair)
            ):
                raise ValueError(
                    f"Scenario.{field_name} must be a pair (lower, upper) of numbers, got {pair!r}"
                )
            lo, hi = pair
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(
                    f"Scenario.{field_name} must be finite (lower, upper) with lower < upper, "
                    f"got {(lo, hi)}"
                )

    @property
    def n_uav(self) -> int:
        """Number of UAVs."""
        return len(self.initial_states)

    @property
    def horizon_s(self) -> float:
        """Prediction horizon Tp in seconds."""
        return self.horizon_steps * self.period_s

    @property
    def trigger_lookahead(self) -> int:
        """Predicted periods after t_c at which conditions (15)-(16) are checked."""
        if self.trigger_lookahead_steps is None:
            return self.horizon_steps
        return self.trigger_lookahead_steps

    @property
    def reference_path(self) -> ReferencePath:
        """The :class:`ReferencePath` named by ``reference``."""
        return REFERENCE_PATHS[self.reference]

    @property
    def control_lower(self) -> np.ndarray:
        """``[a_min, omega_min]``."""
        return np.array([self.accel_bounds[0], self.turn_rate_bounds[0]])

    @property
    def control_upper(self) -> np.ndarray:
        """``[a_max, omega_max]``."""
        return np.array([self.accel_bounds[1], self.turn_rate_bounds[1]])

    def initial_state_array(self) -> np.ndarray:
        """Initial states as an ``(N, 4)`` array."""
        return np.asarray(self.initial_states, dtype=np.float64)

    def reference_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference centre positions ``(T, 2)`` and headings ``(T,)`` at ``times``."""
        start = self.reference_start
        if start is None:
            start = tuple(self.initial_state_array()[:, :2].mean(axis=0))
        return self.reference_path.evaluate(times, start)

    def desired_offsets(self, headings: np.ndarray) -> np.ndarray:
        """World-frame offsets of every UAV from the centre: ``(T, N, 2)``."""
        offsets = np.asarray(self.formation_offsets, dtype=np.float64)
        headings = np.atleast_1d(headings)
        if self.formation_frame == FormationFrame.WORLD:
            return np.broadcast_to(offsets, (headings.size, *offsets.shape)).copy()
        cos, sin = np.cos(headings)[:, None], np.sin(headings)[:, None]
        return np.stack(
            (cos * offsets[:, 0] - sin * offsets[:, 1], sin * offsets[:, 0] + cos * offsets[:, 1]),
            axis=-1,
        )

    def desired_distances(self) -> np.ndarray:
        """Desired distance between every pair of UAVs: ``(N, N)``."""
        offsets = np.asarray(self.formation_offsets, dtype=np.float64)
        return np.linalg.norm(offsets[:, None, :] - offsets[None, :, :], axis=-1)

    def with_overrides(self, **overrides: Any) -> Scenario:
        """A copy with fields replaced (validated); unknown fields are named in the error."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise ValueError(
                f"unknown scenario field(s) {', '.join(unknown)}; "
                f"fields: {', '.join(sorted(names))}"
            )
        return dataclasses.replace(self, **overrides)


PAPER = Scenario()


def _check_scenario(name: str, scenario: Scenario) -> None:
    if not isinstance(scenario, Scenario):
        raise TypeError(f"{name!r}: registered scenarios must be Scenario instances")
    if scenario.name != name:
        raise ValueError(
            f"scenario registered as {name!r} must have name={name!r}, got {scenario.name!r}"
        )


SCENARIOS: Registry[Scenario] = Registry("scenario", SCENARIO_GROUP, _check_scenario)
"""Every registered scenario by name; plugins of the ``formation_bench.scenarios``
entry-point group are loaded on first lookup."""


def register_scenario(scenario: Scenario) -> Scenario:
    """Register ``scenario`` under its ``name``; refuses a name already taken."""
    return SCENARIOS.add(scenario.name, scenario)


register_scenario(PAPER)
register_scenario(dataclasses.replace(PAPER, name="paper-straight", reference="straight"))
register_scenario(dataclasses.replace(PAPER, name="paper-s-curve", reference="s-curve"))


def get_scenario(name: str, /, **overrides: Any) -> Scenario:
    """The scenario registered as ``name``, with fields replaced by ``overrides``."""
    if name not in SCENARIOS:
        raise SCENARIOS.unknown(name)
    scenario = SCENARIOS[name]
    return scenario.with_overrides(**overrides) if overrides else scenario
