"""Derivative-based solvers that need the DMPC problem's structure, not only a batch objective.

They implement the same :class:`~formation_bench.optimizers.Optimizer` protocol as
every black-box optimiser and are registered under their names when this module
is imported (the package declares it in the ``formation_bench.optimizers``
entry-point group, so the registry loads it on first use). Importing it does not
import casadi, osqp or cvxpy: each solver imports them when it first builds a
solver.
"""

from formation_bench.mpc.solvers.ilqr import IlqrOptimizer
from formation_bench.mpc.solvers.ipopt_solver import IpoptOptimizer
from formation_bench.mpc.solvers.ltv_osqp import LtvOsqpOptimizer
from formation_bench.optimizers.registry import register

__all__ = ["IlqrOptimizer", "IpoptOptimizer", "LtvOsqpOptimizer"]

register(
    "ipopt",
    IpoptOptimizer(),
    "IPOPT (CasADi nlpsol) on eq. (14), single shooting, warm primal + dual start; baseline",
)
register(
    "ltv-osqp",
    LtvOsqpOptimizer(),
    "Linear time-varying MPC: QP linearised about the shifted plan, OSQP, 1 SQP round; baseline",
)
register(
    "ilqr",
    IlqrOptimizer(),
    "Iterative LQR on eq. (14), a stage per control block, box QP per stage, line search; baseline",
)
