"""The OSQP workspace driven through OSQP's compiled extension gives what ``osqp.OSQP`` gives."""

from __future__ import annotations

import numpy as np
import pytest

osqp = pytest.importorskip("osqp")
sp = pytest.importorskip("scipy.sparse")

from formation_bench.mpc.solvers.osqp_workspace import OsqpContext  # noqa: E402

SETTINGS = {"eps_abs": 1e-6, "eps_rel": 1e-6, "max_iter": 4000, "verbose": False}


def random_qp(rng: np.random.Generator, n: int, m_extra: int):
    """A convex QP: P upper triangular positive definite, A the identity over extra rows."""
    root = rng.normal(size=(n, n))
    P = sp.csc_matrix(np.triu(root @ root.T + n * np.eye(n)))
    A = sp.csc_matrix(np.vstack((np.eye(n), rng.normal(size=(m_extra, n)))))
    q = rng.normal(size=n)
    lower = np.concatenate((-rng.uniform(0.1, 1.0, n), np.full(m_extra, -np.inf)))
    upper = np.concatenate((rng.uniform(0.1, 1.0, n), rng.uniform(0.5, 2.0, m_extra)))
    return P, q, A, lower, upper


@pytest.mark.parametrize("m_extra", [0, 3])
def test_workspace_solves_are_osqp_solves_to_the_bit(m_extra):
    """Set up, solve, then update the vectors and the matrix values and solve again: the
    extension-driven workspace and the public class return the same bits each time."""
    rng = np.random.default_rng(m_extra)
    context = OsqpContext.build(SETTINGS)
    P, q, A, lower, upper = random_qp(rng, 10, m_extra)
    reference = osqp.OSQP()
    reference.setup(P, q, A, lower, upper, **SETTINGS)
    workspace = context.setup(P, q, A, lower, upper)
    for round_ in range(4):
        expected = reference.solve(raise_error=False)
        outcome = workspace.solve()
        assert outcome.solved == (expected.info.status_val == osqp.SolverStatus.OSQP_SOLVED)
        assert outcome.iterations == expected.info.iter
        np.testing.assert_array_equal(outcome.x, expected.x)
        np.testing.assert_array_equal(outcome.y, expected.y)
        # the next instant: new vectors, and new values on the same patterns
        P2, q, A2, lower, upper = random_qp(np.random.default_rng([m_extra, round_]), 10, m_extra)
        Px, Ax = P2.data, A2.data
        reference.update(q=q, l=lower, u=upper, Px=Px, Ax=Ax)
        workspace.update(q, lower, upper, Px=Px, Ax=Ax)
