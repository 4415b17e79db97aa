"""formation-bench: optimisers inside distributed MPC of UAV formations, compared fairly.

Its packages, dependencies pointing down this list (a test checks the direction and that
no modules import each other in a cycle):

- :mod:`formation_bench.optimizers`: black-box optimisers behind one interface and
  their registry (knows nothing of the harness);
- :mod:`formation_bench.mpc`: the DMPC harness (model, cost, trigger, closed loop) and
  the solvers that need its structure (:mod:`formation_bench.mpc.solvers`);
- :mod:`formation_bench.pipeline`: what a run is, the one path that executes it and what it
  leaves;
- :mod:`formation_bench.instances`: the instance library of recorded local problems;
- :mod:`formation_bench.experiments`: suites, sweeps, the results store and ``score``;
- :mod:`formation_bench.analysis`: statistics, reports and figures over stored results;
- :mod:`formation_bench.cli`: the ``formation-bench`` command.

The performance scripts live beside the package, in the repository's ``perf/`` folder.

:mod:`formation_bench.plugins` loads optimisers and scenarios from other packages.
"""

from __future__ import annotations

__all__ = ["__version__"]


def __getattr__(name: str) -> str:
    # looked up on first use: importlib.metadata takes longer to import than the rest of the
    # package's start, and until the command line has installed its Ctrl-C handler an
    # interrupt prints a traceback
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib import metadata

    try:
        version = metadata.version("formation-bench")
    except metadata.PackageNotFoundError:  # imported from a source tree that was never installed
        version = "0+unknown"
    globals()["__version__"] = version
    return version
