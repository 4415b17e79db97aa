"""The groups of settings a :class:`~formation_bench.mpc.scenario.Scenario` holds.

Each group is a frozen dataclass of declared settings (:func:`formation_bench.fields.setting`),
checked when it is built. A setting's name is unique across the groups of a scenario, so its
errors name it ``Scenario.FIELD`` (the name a caller passes to ``with_overrides``), and a
range end may name a setting of another group (``trigger_lookahead_steps <= horizon_steps``):
a group alone leaves such an end open, and the scenario holding it checks it.

Checks that need the number of UAVs or several groups (per-UAV bounds, the k-nearest graph,
the turn-rate limit per period, a delay below the run's length) are the scenario's.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.fields import check_value, declared, setting

OWNER = "Scenario"
"""The class the settings' errors name: the scenario, whose setting names are unique."""


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


# --- checks of structured values ---------------------------------------------------------------


def is_number(value: object) -> bool:
    """Whether ``value`` is a real number (not a bool)."""
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


def number_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float array, or a ValueError naming the field."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"{OWNER}.{name} must be a tuple of tuples of numbers, got {value!r}"
        ) from None


def number_rows(name: str, value: object, width: int, count: int | None) -> np.ndarray:
    """``value`` as a ``(count, width)`` finite array (any count if None), or a ValueError
    naming the field."""
    if not isinstance(value, tuple | list):
        raise ValueError(f"{OWNER}.{name} must be a tuple of {width}-tuples, got {value!r}")
    rows = np.zeros((0, width))
    if len(value):
        rows = number_array(name, value).reshape(len(value), -1)
    if rows.shape[1] != width or (count is not None and rows.shape[0] != count):
        wanted = f"{count} " if count is not None else ""
        raise ValueError(
            f"{OWNER}.{name} must hold {wanted}{width}-tuples of numbers, got {value!r}"
        )
    if not np.all(np.isfinite(rows)):
        raise ValueError(f"{OWNER}.{name} must be finite, got {value!r}")
    return rows


def check_pair(name: str, pair: object) -> None:
    """A ValueError naming the field unless ``pair`` is finite ``(lower, upper)``, lower < upper."""
    if not (isinstance(pair, tuple | list) and len(pair) == 2 and all(is_number(v) for v in pair)):
        raise ValueError(f"{OWNER}.{name} must be a pair (lower, upper) of numbers, got {pair!r}")
    lo, hi = pair
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(
            f"{OWNER}.{name} must be finite (lower, upper) with lower < upper, got {(lo, hi)}"
        )


def check_within(name: str, value: Any, limit: float, why: str) -> None:
    """A ValueError naming the field if a bound of ``value`` (one ``(lower, upper)`` pair, or
    one per UAV; None: none) passes ``limit``."""
    if value is None:
        return
    pairs = [value] if is_number(value[0]) else value
    # the optimisers sample controls across the bounds: in a box far wider than the
    # controls that keep a formation, almost no sample is usable and every solve keeps
    # its warm start (with accel_bounds=(-1e300, 1e300) every applied control was 0)
    if max(abs(float(v)) for pair in pairs for v in pair) > limit:
        raise ValueError(
            f"{OWNER}.{name} must be within [-{limit:.4g}, {limit:.4g}] ({why}; "
            "the optimisers sample controls across the bounds, so wider bounds leave "
            f"almost no usable control and every solve keeps its warm start), got {value!r}"
        )


# --- the groups --------------------------------------------------------------------------------


class _RangeEnds:
    """Setting values by name, as the range ends that name a setting read them; None (an open
    end) for a name not given."""

    def __init__(self, values: Mapping[str, Any]) -> None:
        self._values = values

    def __getattr__(self, name: str) -> Any:
        return self._values.get(name)


def check_settings(group: SettingGroup, others: Mapping[str, Any]) -> None:
    """Check and normalise every declared field of ``group``, in order; a range end naming a
    setting reads it from the fields checked before it, else from ``others``, else is open."""
    known = dict(others)
    for field in dataclasses.fields(group):
        spec = declared(field)
        if spec is None:
            continue
        value = getattr(group, field.name)
        normal = check_value(_RangeEnds(known), OWNER, field.name, spec, value)
        if normal is not value:
            object.__setattr__(group, field.name, normal)
        known[field.name] = normal


class SettingGroup:
    """Base of the setting groups: its fields are checked when it is built."""

    def __post_init__(self) -> None:
        check_settings(self, {})
        self.check_together()

    def check_together(self) -> None:
        """Checks of the group's fields together, after the declared ranges."""


@dataclass(frozen=True)
class TimingSettings(SettingGroup):
    """The time base: the control period, the prediction horizon and its control blocks, the
    integration sub-steps and the length of the run."""

    period_s: float = setting(
        0.2, low=0.0, low_open=True, doc="Control update period delta_T, seconds"
    )
    horizon_steps: int = setting(
        20, low=1, high=10_000, doc="Prediction horizon in periods (Tp = horizon_steps * period_s)"
    )
    n_steps: int = setting(240, low=1, high=10_000_000, doc="Update instants simulated")
    n_blocks: int = setting(
        5, low=1, high="horizon_steps",
        doc="Control blocks per horizon: the decision vector holds 2 * n_blocks numbers",
    )  # fmt: skip
    """Each control is held over ``horizon_steps / n_blocks`` periods. The default 5 (d = 10)
    was chosen by measurement: see docs/explanation/design.md."""
    rk4_substeps: int = setting(
        1, low=1, high=1000, doc="RK4 sub-steps per control period in prediction and plant"
    )

    @property
    def horizon_s(self) -> float:
        """Prediction horizon Tp in seconds."""
        return self.horizon_steps * self.period_s


@dataclass(frozen=True)
class ControlLimits(SettingGroup):
    """Bounds on the controls (acceleration and turn rate), common or per UAV."""

    accel_bounds: tuple[float, float] = setting(
        (-7.0, 7.0), allowed="finite (lower, upper), lower < upper",
        doc="Bounds on the acceleration a, m/s^2",
    )  # fmt: skip
    turn_rate_bounds: tuple[float, float] = setting(
        (-0.25, 0.25), allowed="finite (lower, upper), lower < upper",
        doc="Bounds on the turn rate omega, rad/s",
    )  # fmt: skip
    uav_accel_bounds: tuple[tuple[float, float], ...] | None = setting(
        None, optional=True, allowed="one finite (lower, upper) per UAV, lower < upper",
        doc="Per-UAV acceleration bounds (mixed vehicles), m/s^2; None = accel_bounds for all",
    )  # fmt: skip
    uav_turn_rate_bounds: tuple[tuple[float, float], ...] | None = setting(
        None, optional=True, allowed="one finite (lower, upper) per UAV, lower < upper",
        doc="Per-UAV turn-rate bounds (mixed vehicles), rad/s; None = turn_rate_bounds for all",
    )  # fmt: skip

    def check_together(self) -> None:
        check_pair("accel_bounds", self.accel_bounds)
        check_pair("turn_rate_bounds", self.turn_rate_bounds)
        self.per_uav_rows(None)
        for name in ("accel_bounds", "uav_accel_bounds"):
            check_within(name, getattr(self, name), MAX_ACCEL_M_S2, "about 10 g, beyond any UAV")

    def per_uav_rows(self, n_uav: int | None) -> None:
        """Check the per-UAV bounds: ``n_uav`` rows each (any number if None), lower < upper."""
        for name in ("uav_accel_bounds", "uav_turn_rate_bounds"):
            value = getattr(self, name)
            if value is None:
                continue
            pairs = number_rows(name, value, 2, n_uav)
            if not np.all(pairs[:, 0] < pairs[:, 1]):
                raise ValueError(
                    f"{OWNER}.{name} must have lower < upper for every UAV, got {value!r}"
                )

    @property
    def lower(self) -> np.ndarray:
        """``[a_min, omega_min]``."""
        return np.array([self.accel_bounds[0], self.turn_rate_bounds[0]])

    @property
    def upper(self) -> np.ndarray:
        """``[a_max, omega_max]``."""
        return np.array([self.accel_bounds[1], self.turn_rate_bounds[1]])

    def of_uav(self, uav: int) -> tuple[np.ndarray, np.ndarray]:
        """``([a_min, omega_min], [a_max, omega_max])`` of UAV ``uav`` (0-based)."""
        lower, upper = self.lower, self.upper
        if self.uav_accel_bounds is not None:
            lower[0], upper[0] = self.uav_accel_bounds[uav]
        if self.uav_turn_rate_bounds is not None:
            lower[1], upper[1] = self.uav_turn_rate_bounds[uav]
        return lower, upper


@dataclass(frozen=True)
class CostWeights(SettingGroup):
    """The weights of the local cost's two terms, eq. (14)."""

    w_dst: float = setting(
        1.0, low=0.0, doc="Weight of the relative-position (formation) term of eq. (14)"
    )
    w_trj: float = setting(
        3.0, low=0.0, doc="Weight of the formation-centre tracking term of eq. (14)"
    )
    """The default 3 (with w_dst = 1) was chosen by measurement: see docs/explanation/design.md."""

    def check_together(self) -> None:
        if self.w_dst == 0 and self.w_trj == 0:
            raise ValueError(
                f"{OWNER}.w_trj must be > 0 when w_dst is 0 (with both weights 0 the cost has "
                "no tracking and no formation term, so every plan is as good as any), got 0.0"
            )


@dataclass(frozen=True)
class TriggerSettings(SettingGroup):
    """The event trigger's thresholds, eqs. (15)-(17), and how far ahead it looks."""

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


@dataclass(frozen=True)
class EvaluationSettings(SettingGroup):
    """What the metrics count: the settle time and the settling bands."""

    settle_time_s: float = setting(
        10.0, low=0.0,
        doc="Metrics of tracking and formation error count from this time on, seconds",
    )  # fmt: skip
    settling_distance_band: float = setting(
        0.02, low=0.0, low_open=True,
        doc="Settling time: every pair's distance error within this fraction of its desired "
        "distance",
    )  # fmt: skip
    settling_tracking_band_m: float = setting(
        1.0, low=0.0, low_open=True,
        doc="Settling time: the formation centre within this distance of the reference, m",
    )  # fmt: skip


@dataclass(frozen=True)
class CommunicationSettings(SettingGroup):
    """Who listens to whom, which plans arrive when, and how a received plan is extended."""

    estimate_extension: EstimateExtension = setting(
        EstimateExtension.COAST,
        doc="How neighbour estimates are extended past the end of their last plan",
    )
    # --- beyond the paper: every field below is off (or the paper's value) by default --------
    graph: CommunicationGraph = setting(
        CommunicationGraph.COMPLETE,
        doc="Communication graph: which UAVs each UAV listens to (complete = the paper)",
    )
    """Each UAV's cost and trigger use only its neighbours' plans; off the complete graph the
    formation centre is estimated from the UAV and its neighbours
    (docs/explanation/scenarios.md)."""
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

    @property
    def faults(self) -> bool:
        """Whether plans can be lost or late."""
        return self.packet_loss > 0 or self.delay_steps > 0 or self.delay_jitter_steps > 0


@dataclass(frozen=True)
class DisturbanceSettings(SettingGroup):
    """What moves the plant and the measurements away from the prediction model: wind,
    measurement noise, model mismatch (all off by default)."""

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

    def check_together(self) -> None:
        wind = self.wind_mean_m_s
        if not (
            isinstance(wind, tuple | list)
            and len(wind) == 2
            and all(is_number(w) and math.isfinite(w) for w in wind)
        ):
            raise ValueError(f"{OWNER}.wind_mean_m_s must be two finite numbers, got {wind!r}")


@dataclass(frozen=True)
class SafetySettings(SettingGroup):
    """No-fly zones, the separation between UAVs, and the penalties that keep them (off by
    default)."""

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

    def check_together(self) -> None:
        obstacles = number_rows("obstacles", self.obstacles, 3, None)
        if np.any(obstacles[:, 2] <= 0):
            raise ValueError(f"{OWNER}.obstacles radii must be > 0, got {self.obstacles!r}")
