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

from importlib import metadata

try:
    __version__ = metadata.version("formation-bench")
except metadata.PackageNotFoundError:  # imported from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = ["__version__"]
