"""The instance library: recorded local problems with their best-known optima.

An *instance* is one UAV's problem of eq. (14) at one update instant, exactly as a closed loop
posed it: the scenario (by registered name and overrides), the UAV, its state, the
neighbours' estimated positions and the desired relative positions over the horizon, the
reference, the group's summed offsets when the formation centre is estimated from the UAV
and its neighbours alone, the bounds and the warm start the loop passed. With it come its
best-known cost ``J*`` and a point ``x*`` reaching it (see
:mod:`formation_bench.instances.build` for how they are drawn and found), the
cost of the warm start, its content hash, its stratum (family, phase, trigger), its split
and whether it is degenerate.

A library is stored as one ``.npz`` file of stacked arrays (in format 2 the neighbour arrays
are padded to the largest neighbour count, with ``neighbour_count`` saying how many rows are
real) and a ``.json`` manifest saying how it was drawn and how ``J*`` was found; format 3
adds which method of the search found each ``J*``. Format 1 (``v1``) stored the first
thirteen arrays only; the fields it lacks are computed on loading (which method found ``J*``
is not known there).
The shipped library is :func:`shipped`; :func:`load_shipped` loads any shipped version.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.mpc.problem import LocalProblem, decision_space, scenario_penalties
from formation_bench.mpc.scenario import Scenario, get_scenario
from formation_bench.pipeline.outputs import atomic_write_bytes
from formation_bench.pipeline.spec import canonical_json, from_json_value, jsonable

DATA_DIR = Path(__file__).parent / "data"
"""Where the shipped library lives."""
LIBRARY_VERSIONS = ("v1", "v2")
"""The shipped library versions, oldest first."""
SHIPPED_VERSION = "v2"
"""The library version :func:`shipped` loads."""
FORMAT_VERSION = 3
"""Layout of the library files the build module writes (``v1`` is format 1; format 2 lacks
``found_by_index``)."""

PHASES = ("start-up", "transient", "steady")
"""Phases of a closed loop by the instant's time ``t = step * period_s``: ``start-up`` (step
0), ``transient`` (``0 < t < settle_time_s``), ``steady`` (``t >= settle_time_s``)."""
SPLITS = ("validation", "test")
"""The splits of a library with splits (``split_index`` 0 and 1)."""
VALIDATION_EVERY = 3
"""Every third instance of a stratum cell, in content-hash order, is a validation instance."""
SPLIT_RULE = (
    "Per stratum cell (family, phase, trigger), instances sorted by content hash (hex, "
    "ascending): positions 0, 3, 6, ... are 'validation', the rest 'test'."
)
"""The split rule, as the manifest states it."""

DEGENERATE_J_STAR = 1e-6
"""Absolute, in cost units: an instance whose ``J*`` is below this is degenerate (its cost is
rounding noise: the compiled and the plain cost disagree there by tens of percent)."""
WARM_START_OPTIMAL = 1e-6
"""Relative: an instance whose warm start is optimal to this, ``warm_cost - J* <= this * J*``,
is degenerate (there is nothing to improve, so a gap says nothing about an optimiser)."""
J_STAR_RTOL = 1e-9
"""Relative part of the tolerance at which the plain eq. (14) at ``x*`` reproduces ``J*``."""
J_STAR_ATOL = 1e-15
"""Absolute part (cost units): ``|plain(x*) - J*| <= J_STAR_RTOL * J* + J_STAR_ATOL``. Measured
on the instances with ``J*`` below 1e-6, where the relative part is no bound: the largest
``|plain(x*) - J*|`` is 2.1e-17 in v1 and 1.3e-17 in v2 (on the others the relative part
holds alone: at most 3.4e-11 relative)."""

V1_ARRAYS = (
    "uav",
    "state",
    "neighbour_positions",
    "desired_relative",
    "reference",
    "warm_start",
    "j_star",
    "x_star",
    "scenario_index",
    "trigger",
    "drawn_by_index",
    "seed",
    "step",
)
"""The arrays of a format-1 library file (``v1``), one row per instance."""
FORMAT2_ARRAYS = (
    *V1_ARRAYS,
    "neighbour_count",
    "centre_offset_sum",
    "has_centre_offset_sum",
    "content_hash",
    "warm_cost",
    "degenerate",
    "phase_index",
    "split_index",
)
"""The arrays of a format-2 library file, one row per instance. ``neighbour_positions`` and
``desired_relative`` are padded with NaN to the largest neighbour count, ``centre_offset_sum``
is NaN where ``has_centre_offset_sum`` is false, ``phase_index`` indexes :data:`PHASES` and
``split_index`` :data:`SPLITS`."""
ARRAYS = (*FORMAT2_ARRAYS, "found_by_index")
"""The arrays of a format-3 library file: format 2's and ``found_by_index``, which indexes the
manifest's ``found_by_methods`` (the method of the search that found each ``J*``)."""
FORMAT_ARRAYS = {1: V1_ARRAYS, 2: FORMAT2_ARRAYS, 3: ARRAYS}
"""The arrays of each file format."""


class LibraryError(ValueError):
    """A library file that cannot be used (one line, naming the file and the problem)."""


# --- what an instance is ------------------------------------------------------------------------


SOLVE_FIELDS = (
    "horizon_steps",
    "n_blocks",
    "period_s",
    "rk4_substeps",
    "w_dst",
    "w_trj",
    "initial_states",
    "accel_bounds",
    "turn_rate_bounds",
    "uav_accel_bounds",
    "uav_turn_rate_bounds",
    "w_collision",
    "safety_radius_m",
    "obstacles",
    "obstacle_margin_m",
    "w_obstacle",
)
"""The scenario fields a local problem is built from (through :func:`solve_setting`); every
other field (the reference's name, faults, wind, noise, trigger thresholds, ...) acts on the
closed loop only, through the arrays of the instance."""


def solve_setting(scenario: Scenario, uav: int) -> dict[str, Any]:
    """What of ``scenario`` UAV ``uav``'s local problem reads, as JSON data: the horizon and
    its blocking, the integration step, the weights, the number of UAVs (eq. (14)'s centre),
    the UAV's decision bounds and the penalties, each as :class:`LocalProblem` derives it."""
    _, bounds = decision_space(scenario, uav)
    penalties = scenario_penalties(scenario)
    return {
        "horizon_steps": scenario.timing.horizon_steps,
        "n_blocks": scenario.timing.n_blocks,
        "period_s": scenario.timing.period_s,
        "rk4_substeps": scenario.timing.rk4_substeps,
        "w_dst": scenario.weights.w_dst,
        "w_trj": scenario.weights.w_trj,
        "n_uav": scenario.n_uav,
        "lower": bounds.lower,
        "upper": bounds.upper,
        "w_collision": penalties.w_collision,
        "safety_radius": penalties.safety_radius,
        "obstacles": penalties.obstacles,
        "w_obstacle": penalties.w_obstacle,
    }


def _floats(value: Any) -> Any:
    """JSON data with every number as a float, so ``3`` and ``3.0`` hash alike."""
    if isinstance(value, list):
        return [_floats(v) for v in value]
    if isinstance(value, dict):
        return {k: _floats(v) for k, v in value.items()}
    if isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def content_hash(
    scenario: Scenario,
    uav: int,
    state: np.ndarray,
    neighbour_positions: np.ndarray,
    desired_relative: np.ndarray,
    reference: np.ndarray,
    centre_offset_sum: np.ndarray | None,
    warm_start: np.ndarray,
) -> str:
    """SHA-256 (hex) of everything that determines a solve of a local problem.

    The scenario as the problem reads it (:func:`solve_setting`, canonical JSON with numbers
    as floats), the UAV index, and the state, neighbour positions, desired relative
    positions, reference, the centre's offset sum (or its absence) and the warm start, each
    as its shape and its float64 bytes (little-endian, row-major). Two instances with the
    same hash pose the same problem from the same start, whatever scenario they came from:
    the start-up of ``paper`` and of ``paper`` with packet loss, say, are one problem.
    """
    digest = hashlib.sha256()
    digest.update(canonical_json(_floats(jsonable(solve_setting(scenario, uav)))).encode())
    digest.update(f"|uav={int(uav)}".encode())
    named = (
        ("state", state),
        ("neighbour_positions", neighbour_positions),
        ("desired_relative", desired_relative),
        ("reference", reference),
        ("centre_offset_sum", centre_offset_sum),
        ("warm_start", warm_start),
    )
    for name, value in named:
        if value is None:
            digest.update(f"|{name}=None".encode())
            continue
        array = np.ascontiguousarray(value, dtype="<f8")
        digest.update(f"|{name}{list(array.shape)}=".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def problem_hash(problem: LocalProblem, warm_start: np.ndarray) -> str:
    """:func:`content_hash` of a :class:`LocalProblem` solved from ``warm_start``."""
    return content_hash(
        problem.scenario,
        problem.uav,
        problem.state,
        problem.neighbour_positions,
        problem.desired_relative,
        problem.reference,
        problem.centre_offset_sum,
        warm_start,
    )


def phase_of(step: int, scenario: Scenario) -> str:
    """The phase (one of :data:`PHASES`) of update instant ``step`` in ``scenario``."""
    if step == 0:
        return "start-up"
    return (
        "transient"
        if step * scenario.timing.period_s < scenario.evaluation.settle_time_s
        else "steady"
    )


def is_degenerate(j_star: float | np.ndarray, warm_cost: float | np.ndarray) -> bool | np.ndarray:
    """Whether ``J*`` is below :data:`DEGENERATE_J_STAR` or the warm start is optimal to
    :data:`WARM_START_OPTIMAL` (relative)."""
    j_star, warm_cost = np.asarray(j_star), np.asarray(warm_cost)
    result = (j_star < DEGENERATE_J_STAR) | (warm_cost - j_star <= WARM_START_OPTIMAL * j_star)
    return bool(result) if result.ndim == 0 else result


def j_star_tolerance(j_star: float) -> float:
    """How far the plain eq. (14) at ``x*`` may be from ``J*``: ``rtol * J* + atol``."""
    return J_STAR_RTOL * abs(j_star) + J_STAR_ATOL


def split_indices(cells: list[Any], hashes: list[str]) -> np.ndarray:
    """Index into :data:`SPLITS` of every instance by :data:`SPLIT_RULE`; ``cells[k]`` is
    instance k's stratum cell (any hashable), ``hashes[k]`` its content hash."""
    split = np.ones(len(hashes), dtype=np.int8)
    members: dict[Any, list[int]] = {}
    for k, cell in enumerate(cells):
        members.setdefault(cell, []).append(k)
    for ks in members.values():
        for position, k in enumerate(sorted(ks, key=lambda k: hashes[k])):
            if position % VALIDATION_EVERY == 0:
                split[k] = 0
    return split


@dataclass(frozen=True)
class Instance:
    """One recorded local problem with its best-known optimum."""

    index: int
    """Position in the library (its identity within a version)."""
    scenario_name: str
    """Registered scenario the closed loop ran."""
    scenario_overrides: str
    """Canonical JSON of the fields changed from the registered scenario."""
    uav: int
    """The UAV whose problem it is (0-based)."""
    state: np.ndarray
    """The UAV's state ``(x, y, heading, speed)`` at the instant."""
    neighbour_positions: np.ndarray
    """Estimated neighbour positions over the horizon, ``(J, H, 2)``."""
    desired_relative: np.ndarray
    """Desired ``p_i - p_j`` over the horizon, ``(J, H, 2)``."""
    reference: np.ndarray
    """Desired formation-centre positions over the horizon, ``(H, 2)``."""
    warm_start: np.ndarray
    """The shifted previous plan the loop passed as ``x0``."""
    j_star: float
    """Best-known cost."""
    x_star: np.ndarray
    """A point with cost ``j_star``."""
    trigger: bool
    """Whether the loop it came from used the event trigger."""
    drawn_by: str
    """The optimiser that flew the loop it came from."""
    seed: int
    """That loop's seed."""
    step: int
    """The update instant c."""
    content_hash: str
    """:func:`content_hash` of the instance: equal hashes, equal problems."""
    family: str
    """Label of the family (scenario and overrides) it was drawn from; v1: the scenario name."""
    phase: str
    """Phase of the loop at the instant, one of :data:`PHASES`."""
    split: str
    """``"validation"`` or ``"test"``; ``""`` in a library without splits (v1)."""
    degenerate: bool
    """``J*`` below :data:`DEGENERATE_J_STAR` or the warm start optimal to
    :data:`WARM_START_OPTIMAL`: kept in the library, left out of the headline."""
    warm_cost: float
    """The compiled cost of the warm start."""
    found_by: str = ""
    """The method of the search for ``J*`` that found it (``"ipopt"``, ``"ipopt random
    start"``, a population optimiser's name, any of them followed by ``" + ipopt polish"``, or
    ``"warm start"``); ``""`` where the library does not record it (formats 1 and 2)."""
    centre_offset_sum: np.ndarray | None = None
    """The UAV's and its neighbours' desired offsets summed, ``(H, 2)``, when the centre is
    estimated from them alone (off the complete graph); None: eq. (14)'s centre."""

    @cached_property
    def scenario(self) -> Scenario:
        return _scenario(self.scenario_name, self.scenario_overrides)

    @cached_property
    def problem(self) -> LocalProblem:
        """The batch objective (with its bounds) of this instance."""
        return LocalProblem(
            self.scenario,
            self.uav,
            self.state,
            self.neighbour_positions,
            self.desired_relative,
            self.reference,
            self.centre_offset_sum,
        )

    def gap(self, cost: float | np.ndarray) -> float | np.ndarray:
        """Relative gap to the best-known cost: ``(cost - J*) / |J*|`` (``J*`` is > 0 here)."""
        return (np.asarray(cost) - self.j_star) / abs(self.j_star)

    def normalised_gap(self, cost: float | np.ndarray) -> float | np.ndarray:
        """``(cost - J*) / (warm_cost - J*)``: 0 at ``J*``, 1 at the warm start's cost; NaN on
        a degenerate instance (its warm start leaves nothing, or only rounding, to gain)."""
        cost = np.asarray(cost, dtype=np.float64)
        if self.degenerate:
            return np.full_like(cost, np.nan)[()]
        return ((cost - self.j_star) / (self.warm_cost - self.j_star))[()]


@functools.lru_cache(maxsize=64)
def _scenario(name: str, overrides: str) -> Scenario:
    return get_scenario(name, **from_json_value(json.loads(overrides)))


@dataclass(frozen=True)
class Library:
    """A versioned set of instances and its manifest.

    ``arrays`` holds the arrays of the library's format (:data:`FORMAT_ARRAYS`), one row per
    instance; a format-1 library gets the fields it lacks computed on first use.
    """

    version: str
    manifest: dict[str, Any]
    arrays: dict[str, np.ndarray]

    @property
    def format_version(self) -> int:
        return int(self.manifest.get("format_version", 1))

    @property
    def has_splits(self) -> bool:
        """Whether the instances are split into :data:`SPLITS` (not in v1)."""
        return self.format_version >= 2

    def __len__(self) -> int:
        return int(self.arrays["j_star"].shape[0])

    def __iter__(self) -> Iterator[Instance]:
        return (self[k] for k in range(len(self)))

    @cached_property
    def _columns(self) -> dict[str, np.ndarray]:
        """The arrays of the current format: stored, or computed for an older one (no
        ``found_by`` recorded: ``found_by_index`` -1)."""
        if self.format_version >= 3:
            return self.arrays
        unknown = {"found_by_index": np.full(len(self), -1, dtype=np.int8)}
        if self.format_version == 2:
            return {**self.arrays, **unknown}
        return {**self.arrays, **_format1_columns(self), **unknown}

    def _scenario_of(self, k: int) -> tuple[dict[str, Any], str]:
        entry = self.manifest["scenarios"][int(self.arrays["scenario_index"][k])]
        return entry, canonical_json(entry["overrides"])

    def __getitem__(self, k: int) -> Instance:
        if not -len(self) <= k < len(self):
            raise IndexError(f"library {self.version} has {len(self)} instances, no {k}")
        k = int(k) % len(self)
        a = self._columns
        entry, overrides = self._scenario_of(k)
        count = int(a["neighbour_count"][k])
        split = int(a["split_index"][k])
        found_by = int(a["found_by_index"][k])
        return Instance(
            index=k,
            scenario_name=entry["name"],
            scenario_overrides=overrides,
            uav=int(a["uav"][k]),
            state=a["state"][k],
            neighbour_positions=a["neighbour_positions"][k, :count],
            desired_relative=a["desired_relative"][k, :count],
            reference=a["reference"][k],
            warm_start=a["warm_start"][k],
            j_star=float(a["j_star"][k]),
            x_star=a["x_star"][k],
            trigger=bool(a["trigger"][k]),
            drawn_by=self.manifest["drawn_by"][int(a["drawn_by_index"][k])],
            seed=int(a["seed"][k]),
            step=int(a["step"][k]),
            content_hash=str(a["content_hash"][k]),
            family=entry.get("family", entry["name"]),
            phase=PHASES[int(a["phase_index"][k])],
            split=SPLITS[split] if split >= 0 else "",
            degenerate=bool(a["degenerate"][k]),
            warm_cost=float(a["warm_cost"][k]),
            found_by=self.manifest["found_by_methods"][found_by] if found_by >= 0 else "",
            centre_offset_sum=(
                a["centre_offset_sum"][k] if bool(a["has_centre_offset_sum"][k]) else None
            ),
        )

    def instances(
        self, split: str | None = None, *, degenerate: bool | None = False
    ) -> list[Instance]:
        """The instances of ``split`` (None: every split), by default the non-degenerate ones
        (the headline); ``degenerate=True`` gives the degenerate ones only, None both."""
        a = self._columns
        keep = np.ones(len(self), dtype=bool)
        if split is not None:
            if not self.has_splits:
                raise LibraryError(
                    f"library {self.version} has no splits (it predates them); ask for split=None"
                )
            if split not in SPLITS:
                raise LibraryError(
                    f"unknown split {split!r} of library {self.version}; "
                    f"splits: {', '.join(SPLITS)}"
                )
            keep &= a["split_index"] == SPLITS.index(split)
        if degenerate is not None:
            keep &= a["degenerate"].astype(bool) == bool(degenerate)
        return [self[int(k)] for k in np.flatnonzero(keep)]

    def save(self, folder: Path) -> tuple[Path, Path]:
        """Write ``VERSION.npz`` and ``VERSION.json`` into ``folder`` (each atomically)."""
        import io

        buffer = io.BytesIO()
        stored = {name: self.arrays[name] for name in FORMAT_ARRAYS[self.format_version]}
        np.savez_compressed(buffer, **stored)
        data = folder / f"{self.version}.npz"
        manifest = folder / f"{self.version}.json"
        atomic_write_bytes(data, buffer.getvalue())
        atomic_write_bytes(manifest, (json.dumps(self.manifest, indent=2) + "\n").encode())
        return data, manifest


def _format1_columns(library: Library) -> dict[str, np.ndarray]:
    """What format 2 stores and format 1 does not, computed: every neighbour row is real,
    the centre is eq. (14)'s, the warm cost by the compiled cost, no splits."""
    a = library.arrays
    n = len(library)
    hashes, warm_cost, phase = [], np.empty(n), np.empty(n, dtype=np.int8)
    for k in range(n):
        entry, overrides = library._scenario_of(k)
        scenario = _scenario(entry["name"], overrides)
        uav, step = int(a["uav"][k]), int(a["step"][k])
        problem = LocalProblem(
            scenario,
            uav,
            a["state"][k],
            a["neighbour_positions"][k],
            a["desired_relative"][k],
            a["reference"][k],
        )
        warm_cost[k] = problem(a["warm_start"][k][None])[0]
        hashes.append(problem_hash(problem, a["warm_start"][k]))
        phase[k] = PHASES.index(phase_of(step, scenario))
    return {
        "neighbour_count": np.full(n, a["neighbour_positions"].shape[1], dtype=np.int16),
        "centre_offset_sum": np.full((n, *a["reference"].shape[1:]), np.nan),
        "has_centre_offset_sum": np.zeros(n, dtype=bool),
        "content_hash": np.array(hashes, dtype="<U64"),
        "warm_cost": warm_cost,
        "degenerate": np.asarray(is_degenerate(a["j_star"], warm_cost), dtype=bool),
        "phase_index": phase,
        "split_index": np.full(n, -1, dtype=np.int8),
    }


def load(folder: Path | str, version: str) -> Library:
    """The library ``version`` stored in ``folder``; raises :class:`LibraryError`."""
    folder = Path(folder)
    data, manifest_path = folder / f"{version}.npz", folder / f"{version}.json"
    for path in (data, manifest_path):
        if not path.is_file():
            raise LibraryError(f"{path}: no such library file")
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        layout = int(manifest.get("format_version", 1))
        if layout not in FORMAT_ARRAYS:
            raise LibraryError(
                f"{manifest_path}: unknown library format {layout} "
                f"(known: {', '.join(map(str, FORMAT_ARRAYS))})"
            )
        with np.load(data) as stored:
            arrays = {name: stored[name] for name in FORMAT_ARRAYS[layout]}
    except (OSError, ValueError, KeyError, TypeError) as err:
        if isinstance(err, LibraryError):
            raise
        raise LibraryError(f"{data}: not a library file ({err})") from None
    sizes = {name: len(array) for name, array in arrays.items()}
    if len(set(sizes.values())) != 1:
        raise LibraryError(f"{data}: arrays of different lengths {sizes}")
    if "found_by_index" in arrays:
        methods = len(manifest.get("found_by_methods", ()))
        index = arrays["found_by_index"]
        if index.size and not (index.min() >= -1 and index.max() < methods):
            raise LibraryError(
                f"{data}: found_by_index outside the manifest's {methods} found_by_methods"
            )
    return Library(version, manifest, arrays)


@functools.cache
def load_shipped(version: str) -> Library:
    """The shipped library ``version`` (one of :data:`LIBRARY_VERSIONS`; read once per
    process)."""
    if version not in LIBRARY_VERSIONS:
        raise LibraryError(
            f"no shipped library {version!r}; shipped: {', '.join(LIBRARY_VERSIONS)}"
        )
    return load(DATA_DIR, version)


def shipped() -> Library:
    """The library that comes with the package, :data:`SHIPPED_VERSION` (read once per
    process)."""
    return load_shipped(SHIPPED_VERSION)
