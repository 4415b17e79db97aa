"""The instance library: recorded local problems with their best-known optima.

An *instance* is one UAV's problem of eq. (14) at one update instant, exactly as a closed loop
posed it: the scenario (by registered name and overrides), the UAV, its state, the
neighbours' estimated positions and the desired relative positions over the horizon, the
reference, the bounds and the warm start the loop passed. With it come its best-known cost
``J*`` and a point ``x*`` reaching it (see :mod:`formation_bench.benchmarks.instances.build`
for how they are found) and where the instance was drawn from.

A library is stored as one ``.npz`` file of stacked arrays (every instance of a version has
the same shape) and a ``.json`` manifest saying how it was drawn and how ``J*`` was found.
The shipped library is :func:`shipped`.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.benchmarks.outputs import atomic_write_bytes
from formation_bench.benchmarks.spec import canonical_json, from_json_value
from formation_bench.mpc.problem import LocalProblem
from formation_bench.mpc.scenario import Scenario, get_scenario

DATA_DIR = Path(__file__).parent / "data"
"""Where the shipped library lives."""
SHIPPED_VERSION = "v1"
"""The library version :func:`shipped` loads."""

ARRAYS = (
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
"""The arrays of a library file, one row per instance."""


class LibraryError(ValueError):
    """A library file that cannot be used (one line, naming the file and the problem)."""


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

    @cached_property
    def scenario(self) -> Scenario:
        overrides = from_json_value(json.loads(self.scenario_overrides))
        return get_scenario(self.scenario_name, **overrides)

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
        )

    def gap(self, cost: float | np.ndarray) -> float | np.ndarray:
        """Relative gap to the best-known cost: ``(cost - J*) / |J*|`` (``J*`` is > 0 here)."""
        return (np.asarray(cost) - self.j_star) / abs(self.j_star)


@dataclass(frozen=True)
class Library:
    """A versioned set of instances and its manifest."""

    version: str
    manifest: dict[str, Any]
    arrays: dict[str, np.ndarray]

    def __len__(self) -> int:
        return int(self.arrays["j_star"].shape[0])

    def __iter__(self) -> Iterator[Instance]:
        return (self[k] for k in range(len(self)))

    def __getitem__(self, k: int) -> Instance:
        a = self.arrays
        scenario = self.manifest["scenarios"][int(a["scenario_index"][k])]
        return Instance(
            index=k,
            scenario_name=scenario["name"],
            scenario_overrides=canonical_json(scenario["overrides"]),
            uav=int(a["uav"][k]),
            state=a["state"][k],
            neighbour_positions=a["neighbour_positions"][k],
            desired_relative=a["desired_relative"][k],
            reference=a["reference"][k],
            warm_start=a["warm_start"][k],
            j_star=float(a["j_star"][k]),
            x_star=a["x_star"][k],
            trigger=bool(a["trigger"][k]),
            drawn_by=self.manifest["drawn_by"][int(a["drawn_by_index"][k])],
            seed=int(a["seed"][k]),
            step=int(a["step"][k]),
        )

    def save(self, folder: Path) -> tuple[Path, Path]:
        """Write ``VERSION.npz`` and ``VERSION.json`` into ``folder`` (each atomically)."""
        import io

        buffer = io.BytesIO()
        np.savez_compressed(buffer, **self.arrays)
        data = folder / f"{self.version}.npz"
        manifest = folder / f"{self.version}.json"
        atomic_write_bytes(data, buffer.getvalue())
        atomic_write_bytes(manifest, (json.dumps(self.manifest, indent=2) + "\n").encode())
        return data, manifest


def load(folder: Path | str, version: str) -> Library:
    """The library ``version`` stored in ``folder``; raises :class:`LibraryError`."""
    folder = Path(folder)
    data, manifest_path = folder / f"{version}.npz", folder / f"{version}.json"
    for path in (data, manifest_path):
        if not path.is_file():
            raise LibraryError(f"{path}: no such library file")
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        with np.load(data) as stored:
            arrays = {name: stored[name] for name in ARRAYS}
    except (OSError, ValueError, KeyError) as err:
        raise LibraryError(f"{data}: not a library file ({err})") from None
    sizes = {name: len(array) for name, array in arrays.items()}
    if len(set(sizes.values())) != 1:
        raise LibraryError(f"{data}: arrays of different lengths {sizes}")
    return Library(version, manifest, arrays)


@functools.cache
def shipped() -> Library:
    """The library that comes with the package (read once per process)."""
    return load(DATA_DIR, SHIPPED_VERSION)
