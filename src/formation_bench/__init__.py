"""formation-bench: optimisers inside distributed MPC of UAV formations, compared fairly.

The installed namespace holds three packages:

- :mod:`formation_bench.optimizers`: black-box optimisers behind one interface and
  their registry (knows nothing of the harness);
- :mod:`formation_bench.mpc`: the DMPC harness (model, cost, trigger, closed loop) and
  the solvers that need its structure (:mod:`formation_bench.mpc.solvers`);
- :mod:`formation_bench.benchmarks`: the command line, the run pipeline, sweeps,
  statistics, figures and the performance scripts.

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
