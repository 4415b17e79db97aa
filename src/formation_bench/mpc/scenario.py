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


class CommunicationGraph(enum.StrEnum):
    """Which UAVs each UAV listens to (its neighbours) at an update instant."""

    COMPLETE = "complete"
    """Every other UAV (the paper)."""
    RING = "ring"
    """The UAVs before and after it in index order (1 with 2 and N, and so on); fixed."""
    K_NEAREST = "k-nearest"
    """Its ``graph_neighbours`` nearest UAVs at the instant; changes as the UAVs move."""
    RANGE = "range"
    """Every UAV within ``graph_range_m`` at the instant; changes as the UAVs move."""


class EstimateExtension(enum.StrEnum):
    """How a neighbour's estimate is extended past the end of its last plan."""

    COAST = "coast"
    """Propagate the plan's terminal state with zero control (constant speed and heading)."""
    HOLD = "hold"
    """Hold the plan's terminal position (the literal reading of Section 2.2)."""


MAX_ACCEL_M_S2 = 100.0
"""Largest acceleration bound, m/s^2 (about 10 g). The paper's UAVs are bounded at 7. Measured
on its scenario (seed 0, trigger on, largest tracking error): +-100 still tracks within
1.2 m, +-1000 loses the reference by 17 m (PSO) to 147 m (modified BSO), +-1e300 by 310 m."""


def _rows(name: str, value: object, width: int, count: int | None) -> np.ndarray:
    """``value`` as a ``(count, width)`` finite array (any count if None), or a ValueError
    naming the field."""
    if not isinstance(value, tuple | list):
        raise ValueError(f"Scenario.{name} must be a tuple of {width}-tuples, got {value!r}")
    rows = np.zeros((0, width))
    if len(value):
        rows = _number_array(name, value).reshape(len(value), -1)
    if rows.shape[1] != width or (count is not None and rows.shape[0] != count):
        wanted = f"{count} " if count is not None else ""
        raise ValueError(
            f"Scenario.{name} must hold {wanted}{width}-tuples of numbers, got {value!r}"
        )
    if not np.all(np.isfinite(rows)):
        raise ValueError(f"Scenario.{name} must be finite, got {value!r}")
    return rows


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

    # --- beyond the paper: every field below is off (or the paper's value) by default --------
    graph: CommunicationGraph = setting(
        CommunicationGraph.COMPLETE,
        doc="Communication graph: which UAVs each UAV listens to (complete = the paper)",
    )
    """Each UAV's cost and trigger use only its neighbours' plans; off the complete graph the
    formation centre is estimated from the UAV and its neighbours (docs/scenarios.md)."""
    graph_neighbours: int = setting(
        2, low=1, doc="k of the k-nearest graph: neighbours each UAV listens to"
    )
    graph_range_m: float = setting(
        30.0, low=0.0, low_open=True, doc="Radio range of the range-limited graph, m"
    )
    packet_loss: float = setting(
        0.0, low=0.0, high=1.0, high_open=True,
        doc="Probability that a plan sent over a link is lost (long-run share)",
    )  # fmt: skip
    loss_correlation: float = setting(
        0.0, low=0.0, high=1.0, high_open=True,
        doc="Burstiness of losses: 0 independent; rho makes a link's loss state persist "
        "(mean burst 1 / ((1 - packet_loss) (1 - rho)) periods)",
    )  # fmt: skip
    delay_steps: int = setting(
        0, low=0, high=1000, doc="Whole periods by which every plan arrives late"
    )
    delay_jitter_steps: int = setting(
        0, low=0, high=1000,
        doc="Extra delay of each plan, uniform over 0 .. this many periods (seeded)",
    )  # fmt: skip
    wind_mean_m_s: tuple[float, float] = setting(
        (0.0, 0.0), allowed="two finite numbers",
        doc="Constant part of the wind (x, y), m/s: moves the plant, not the prediction",
    )  # fmt: skip
    gust_std_m_s: float = setting(
        0.0, low=0.0,
        doc="Standard deviation of each UAV's gusts per axis (Ornstein-Uhlenbeck), m/s",
    )  # fmt: skip
    gust_time_constant_s: float = setting(
        2.0, low=0.0, low_open=True, doc="Correlation time of the gusts, s"
    )
    position_noise_std_m: float = setting(
        0.0, low=0.0, doc="Noise on the position each UAV measures of itself, per axis, m"
    )
    heading_noise_std_rad: float = setting(
        0.0, low=0.0, doc="Noise on the heading each UAV measures of itself, rad"
    )
    speed_noise_std_m_s: float = setting(
        0.0, low=0.0, doc="Noise on the speed each UAV measures of itself, m/s"
    )
    plant_accel_gain: float = setting(
        1.0, low=0.0, low_open=True,
        doc="Model mismatch: the plant's acceleration is this times the commanded one",
    )  # fmt: skip
    plant_turn_rate_gain: float = setting(
        1.0, low=0.0, low_open=True,
        doc="Model mismatch: the plant's turn rate is this times the commanded one",
    )  # fmt: skip
    obstacles: tuple[tuple[float, float, float], ...] = setting(
        (), allowed="(x, y, radius) triples, radius > 0",
        doc="Circular no-fly zones (centre x m, centre y m, radius m)",
    )  # fmt: skip
    obstacle_margin_m: float = setting(
        2.0, low=0.0, doc="The obstacle penalty starts this far outside an obstacle's radius, m"
    )
    w_obstacle: float = setting(
        0.0, low=0.0, doc="Weight of the obstacle penalty in the local cost (0 = off)"
    )
    safety_radius_m: float = setting(
        3.0, low=0.0, low_open=True,
        doc="Two UAVs closer than this collide (metrics); the collision penalty starts here, m",
    )  # fmt: skip
    w_collision: float = setting(
        0.0, low=0.0,
        doc="Weight of the collision penalty against neighbours' estimates (0 = off)",
    )  # fmt: skip
    uav_accel_bounds: tuple[tuple[float, float], ...] | None = setting(
        None, optional=True, allowed="one finite (lower, upper) per UAV, lower < upper",
        doc="Per-UAV acceleration bounds (mixed vehicles), m/s^2; None = accel_bounds for all",
    )  # fmt: skip
    uav_turn_rate_bounds: tuple[tuple[float, float], ...] | None = setting(
        None, optional=True, allowed="one finite (lower, upper) per UAV, lower < upper",
        doc="Per-UAV turn-rate bounds (mixed vehicles), rad/s; None = turn_rate_bounds for all",
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
        wind = self.wind_mean_m_s
        if not (
            isinstance(wind, tuple | list)
            and len(wind) == 2
            and all(_is_number(w) and math.isfinite(w) for w in wind)
        ):
            raise ValueError(f"Scenario.wind_mean_m_s must be two finite numbers, got {wind!r}")
        obstacles = _rows("obstacles", self.obstacles, 3, None)
        if np.any(obstacles[:, 2] <= 0):
            raise ValueError(f"Scenario.obstacles radii must be > 0, got {self.obstacles!r}")
        for field_name in ("uav_accel_bounds", "uav_turn_rate_bounds"):
            value = getattr(self, field_name)
            if value is None:
                continue
            pairs = _rows(field_name, value, 2, self.n_uav)
            if not np.all(pairs[:, 0] < pairs[:, 1]):
                raise ValueError(
                    f"Scenario.{field_name} must have lower < upper for every UAV, got {value!r}"
                )
        if self.graph == CommunicationGraph.K_NEAREST and self.graph_neighbours >= self.n_uav:
            raise ValueError(
                f"Scenario.graph_neighbours must be below the number of UAVs ({self.n_uav}) "
                f"on the k-nearest graph, got {self.graph_neighbours}"
            )
        self._check_meaningful()

    def _check_meaningful(self) -> None:
        """Refuse values that are each allowed but together leave nothing to optimise."""
        # the optimisers sample controls across the bounds: in a box far wider than the
        # controls that keep a formation, almost no sample is usable and every solve keeps
        # its warm start (with accel_bounds=(-1e300, 1e300) every applied control was 0)
        turn_limit = math.pi / self.period_s
        for field_name, limit, why in (
            ("accel_bounds", MAX_ACCEL_M_S2, "about 10 g, beyond any UAV"),
            ("uav_accel_bounds", MAX_ACCEL_M_S2, "about 10 g, beyond any UAV"),
            ("turn_rate_bounds", turn_limit, "half a turn per period: pi / period_s"),
            ("uav_turn_rate_bounds", turn_limit, "half a turn per period: pi / period_s"),
        ):
            value = getattr(self, field_name)
            pairs = [value] if field_name in ("accel_bounds", "turn_rate_bounds") else value
            if pairs is not None and max(abs(float(v)) for pair in pairs for v in pair) > limit:
                raise ValueError(
                    f"Scenario.{field_name} must be within [-{limit:.4g}, {limit:.4g}] ({why}; "
                    "the optimisers sample controls across the bounds, so wider bounds leave "
                    f"almost no usable control and every solve keeps its warm start), got {value!r}"
                )
        if self.w_dst == 0 and self.w_trj == 0:
            raise ValueError(
                "Scenario.w_trj must be > 0 when w_dst is 0 (with both weights 0 the cost has "
                "no tracking and no formation term, so every plan is as good as any), got 0.0"
            )
        if self.delay_steps > 0 and self.delay_steps + 1 >= self.n_steps:
            raise ValueError(
                f"Scenario.delay_steps must be below n_steps - 1 = {self.n_steps - 1} (a plan "
                "arrives delay_steps + 1 instants after it is sent, so no plan would reach a "
                f"neighbour before the run ends), got {self.delay_steps}"
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

    def control_bounds_of(self, uav: int) -> tuple[np.ndarray, np.ndarray]:
        """``([a_min, omega_min], [a_max, omega_max])`` of UAV ``uav`` (0-based)."""
        lower, upper = self.control_lower, self.control_upper
        if self.uav_accel_bounds is not None:
            lower[0], upper[0] = self.uav_accel_bounds[uav]
        if self.uav_turn_rate_bounds is not None:
            lower[1], upper[1] = self.uav_turn_rate_bounds[uav]
        return lower, upper

    @property
    def communication_faults(self) -> bool:
        """Whether plans can be lost or late."""
        return self.packet_loss > 0 or self.delay_steps > 0 or self.delay_jitter_steps > 0

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
register_scenario(
    dataclasses.replace(
        PAPER,
        name="paper-obstacles",
        obstacles=((136.0, -4.0, 5.0), (392.0, 112.0, 5.0)),
        w_obstacle=100.0,
        w_collision=100.0,
    )
)
"""The paper's scenario with two no-fly zones: one on the straight leg, on the reference
centre's line (the trailing UAV's slot), one beside the turn; both penalties on."""


def get_scenario(name: str, /, **overrides: Any) -> Scenario:
    """The scenario registered as ``name``, with fields replaced by ``overrides``."""
    if name not in SCENARIOS:
        raise SCENARIOS.unknown(name)
    scenario = SCENARIOS[name]
    return scenario.with_overrides(**overrides) if overrides else scenario


# the swarms are built from the formation library, which builds on Scenario: imported last
from formation_bench.mpc import formations as _formations  # noqa: E402, F401
