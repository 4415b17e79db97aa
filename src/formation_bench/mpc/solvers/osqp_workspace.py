"""OSQP driven through its compiled extension: a set-up in microseconds, nothing looked up per call.

``osqp.OSQP`` (the Python class) spends about 0.2 ms of Python on every ``setup`` of a
10-variable QP: its constructor looks for the optional CUDA and MKL algebras with
``importlib.import_module`` (eight failed module searches, ``find_spec`` and ``stat``, per
instance), and ``setup`` converts, copies and checks the matrices with SciPy. The C set-up
itself (scaling, ordering, factorisation) takes about 8 µs, an ``update`` of the matrix values
4 µs and a warm-started solve 5-10 µs. :class:`OsqpContext` resolves the extension module, its
constants and the settings object once per configuration, and :class:`QPWorkspace` calls the
extension directly, in the order and with the arguments ``osqp.OSQP`` passes, so a solve is
bit for bit the one the Python class would give.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import scipy.sparse as sp


@dataclass
class OsqpContext:
    """The OSQP extension and the settings of one configuration, resolved once."""

    extension: ModuleType
    """OSQP's compiled module for its default algebra (what ``osqp.OSQP()`` picks)."""
    setup_settings: Any
    """``OSQPSettings`` every workspace is set up with (never changed after construction)."""
    limit_settings: Any
    """A copy whose ``time_limit`` is set per call when a deadline applies."""
    infinity: float
    """``OSQP_INFTY``: bounds beyond it are clipped to it, as ``osqp.OSQP`` does."""
    solved: int
    """The ``status_val`` of a solved QP."""
    default_time_limit: float
    """OSQP's own ``time_limit`` (no limit in practice)."""

    @classmethod
    def build(cls, settings: dict[str, Any]) -> OsqpContext:
        """The context of the settings ``settings`` (OSQP's names, as ``OSQP.setup`` takes)."""
        import osqp

        extension = osqp.OSQP().ext  # the algebra the Python class selects, looked up once
        setup_settings = _settings(extension, settings)
        return cls(
            extension=extension,
            setup_settings=setup_settings,
            limit_settings=_settings(extension, settings),
            infinity=float(extension.OSQP_INFTY),
            solved=int(osqp.SolverStatus.OSQP_SOLVED),
            default_time_limit=float(setup_settings.time_limit),
        )

    def setup(
        self,
        P: sp.csc_matrix,
        q: np.ndarray,
        A: sp.csc_matrix,
        lower: np.ndarray,
        upper: np.ndarray,
    ) -> QPWorkspace:
        """A new workspace of the QP ``(P, q, A, l, u)`` (P upper triangular, CSC, sorted)."""
        start = time.perf_counter()
        ext = self.extension
        m, n = A.shape
        solver = ext.OSQPSolver(
            ext.CSC(P),
            q,
            ext.CSC(A),
            np.maximum(lower, -self.infinity),
            np.minimum(upper, self.infinity),
            m,
            n,
            self.setup_settings,
        )
        return QPWorkspace(self, solver, time.perf_counter() - start, self.default_time_limit)


@dataclass
class QPWorkspace:
    """One QP's OSQP solver: updated in place, solved, its solution read."""

    context: OsqpContext
    solver: Any
    """The extension's ``OSQPSolver``."""
    setup_time_s: float
    time_limit: float
    """The ``time_limit`` the solver holds."""

    def update(
        self,
        q: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
        Px: np.ndarray | None = None,
        Ax: np.ndarray | None = None,
    ) -> None:
        """New vectors and matrix values on the pattern set up (``OSQP.update``'s order: the
        vectors, then the matrices)."""
        infinity = self.context.infinity
        self.solver.update_data_vec(
            q=q, l=np.maximum(lower, -infinity), u=np.minimum(upper, infinity)
        )
        if Px is not None or Ax is not None:
            self.solver.update_data_mat(P_x=Px, P_i=None, A_x=Ax, A_i=None)

    def limit_time(self, seconds: float | None) -> None:
        """OSQP's ``time_limit`` for the next solves; None: OSQP's default (no limit)."""
        limit = self.context.default_time_limit if seconds is None else seconds
        if limit != self.time_limit:
            settings = self.context.limit_settings
            settings.time_limit = limit
            self.solver.update_settings(settings)
            self.time_limit = limit

    def solve(self) -> QPOutcome:
        """Solve; the status and the solution (a copy) of this solve."""
        self.solver.solve()
        info = self.solver.info
        return QPOutcome(
            solved=info.status_val == self.context.solved,
            status=str(info.status),
            iterations=int(info.iter),
            run_time_s=float(info.run_time),
            x=self.solver.solution.x,
            y=self.solver.solution.y,
        )


@dataclass(frozen=True)
class QPOutcome:
    """What one OSQP solve returned."""

    solved: bool
    status: str
    iterations: int
    run_time_s: float
    x: np.ndarray
    """The primal solution (the extension returns a new array every time)."""
    y: np.ndarray
    """The multipliers of the rows of A."""


def _settings(extension: ModuleType, values: dict[str, Any]) -> Any:
    """OSQP's default settings with ``values`` set, as ``OSQP.setup`` builds them."""
    settings = extension.OSQPSettings()
    extension.osqp_set_default_settings(settings)
    for name, value in values.items():
        if not hasattr(settings, name):
            raise ValueError(f"unknown OSQP setting {name!r}")
        setattr(settings, name, value)
    return settings
