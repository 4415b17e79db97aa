"""A plugin for the tuning tests: ``tunable-pso``, PSO with search ranges on a few settings
(one limit naming an earlier field, one log scale, one enumeration), so that the tests do not
depend on the ranges the shipped optimisers declare.

Loaded with ``--plugin`` (in a subprocess or a worker) it registers the name; imported by a
test under another module name it only defines the class, which the test puts in the
registry for its own duration."""

from dataclasses import dataclass

from formation_bench.fields import Search, setting
from formation_bench.optimizers import PSO, register
from formation_bench.optimizers.bound_handling import BoundHandling


@dataclass(frozen=True)
class TunablePSO(PSO):
    """PSO whose inertia, velocity clamp and bound handling are searched."""

    inertia_start: float = setting(
        0.9, low=0.0, high=2.0, kernel=True, doc="Inertia weight at the first iteration",
        search=Search(0.3, 1.2),
    )  # fmt: skip
    inertia_end: float = setting(
        0.4, low=0.0, high=2.0, kernel=True, doc="Inertia weight at the last planned iteration",
        search=Search(0.1, "inertia_start"),
    )  # fmt: skip
    velocity_clamp: float = setting(
        0.2, low=0.0, high=2.0, low_open=True, doc="v_max as a fraction of each coordinate's range",
        search=Search(0.02, 1.0, log=True),
    )  # fmt: skip
    bound_handling: BoundHandling = setting(
        BoundHandling.CLIP, kernel=True, doc="How positions outside the box are brought back",
        search=Search(),
    )  # fmt: skip


NAME = "tunable-pso"
DESCRIPTION = "PSO with searched settings (the tuning tests' plugin)"

if __name__.startswith("formation_bench_plugin_"):  # the module name --plugin gives a file
    register(NAME, TunablePSO(), DESCRIPTION)
