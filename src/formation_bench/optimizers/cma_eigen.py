"""The symmetric eigendecomposition of CMA-ES's covariance matrix, compiled.

A Householder tridiagonalisation and implicit QL iteration (:func:`eigen_into`, the EISPACK
``tred2``/``tql2`` algorithm of Wilkinson & Reinsch's *Handbook for Automatic Computation*,
vol. II, 1971; Hansen's C and Java CMA-ES decompose C the same way). At n = 10 it takes
less than half the time of LAPACK's ``eigh`` called from compiled code (``np.linalg.eigh``),
whose decompositions would take about 30 % of a solve of the paper problem (figures in
:mod:`.cma_ops`).
"""

from __future__ import annotations

import math

import numpy as np

from formation_bench.kernel_cache import njit


def symmetric_eigen(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(values, rows)``: eigenvalues of the symmetric ``a`` and its eigenvectors as rows.

    :func:`eigen_into` on a copy of ``a``. Eigenvalues are not sorted;
    ``rows[k]`` belongs to ``values[k]``. The caller scales ``a`` so that its
    entries are of order one (the QL step squares them without the guard of
    ``hypot``).
    """
    n = a.shape[0]
    values, rows = np.empty(n), np.empty((n, n))
    eigen_into(np.array(a, dtype=np.float64), values, np.empty(n), rows)
    return values, rows


# error_model="numpy": no zero check per division (the QL step divides only by values it
# has shown to be nonzero), which makes the decomposition about a fifth faster
@njit(cache=True, error_model="numpy")
def eigen_into(v: np.ndarray, d: np.ndarray, e: np.ndarray, w: np.ndarray) -> None:
    """Eigenvalues of the symmetric ``v`` (n x n, destroyed) into ``d``, eigenvectors as rows
    into ``w``; ``e`` is a work array of length n.

    Householder reduction to tridiagonal form with the transformation
    accumulated (``tred2``), then the implicit QL iteration (``tql2``), as in
    Wilkinson & Reinsch's *Handbook* (1971, contributions II/2 and II/3).
    """
    n = v.shape[0]
    for j in range(n):
        d[j] = v[n - 1, j]
    # Householder: row i is reduced using the part left of the diagonal
    for i in range(n - 1, 0, -1):
        scale = 0.0
        h = 0.0
        for k in range(i):
            scale += abs(d[k])
        if scale == 0.0:
            e[i] = d[i - 1]
            for j in range(i):
                d[j] = v[i - 1, j]
                v[i, j] = 0.0
                v[j, i] = 0.0
        else:
            for k in range(i):
                d[k] /= scale
                h += d[k] * d[k]
            f = d[i - 1]
            g = math.sqrt(h)
            if f > 0:
                g = -g
            e[i] = scale * g
            h -= f * g
            d[i - 1] = f - g
            for j in range(i):
                e[j] = 0.0
            for j in range(i):
                f = d[j]
                v[j, i] = f
                g = e[j] + v[j, j] * f
                for k in range(j + 1, i):
                    g += v[k, j] * d[k]
                    e[k] += v[k, j] * f
                e[j] = g
            f = 0.0
            for j in range(i):
                e[j] /= h
                f += e[j] * d[j]
            hh = f / (h + h)
            for j in range(i):
                e[j] -= hh * d[j]
            for j in range(i):
                f = d[j]
                g = e[j]
                for k in range(j, i):
                    v[k, j] -= f * e[k] + g * d[k]
                d[j] = v[i - 1, j]
                v[i, j] = 0.0
        d[i] = h
    # accumulate the transformations
    for i in range(n - 1):
        v[n - 1, i] = v[i, i]
        v[i, i] = 1.0
        h = d[i + 1]
        if h != 0.0:
            for k in range(i + 1):
                d[k] = v[k, i + 1] / h
            for j in range(i + 1):
                g = 0.0
                for k in range(i + 1):
                    g += v[k, i + 1] * v[k, j]
                for k in range(i + 1):
                    v[k, j] -= g * d[k]
        for k in range(i + 1):
            v[k, i + 1] = 0.0
    for j in range(n):
        d[j] = v[n - 1, j]
        v[n - 1, j] = 0.0
    v[n - 1, n - 1] = 1.0
    # QL on the tridiagonal (d, e), rotating the rows of w (contiguous: the loop vectorises)
    for i in range(n):
        for j in range(n):
            w[i, j] = v[j, i]
    for i in range(1, n):
        e[i - 1] = e[i]
    e[n - 1] = 0.0
    f = 0.0
    tst1 = 0.0
    eps = 2.0**-52
    for m0 in range(n):
        tst1 = max(tst1, abs(d[m0]) + abs(e[m0]))
        m = m0
        while m < n - 1:
            if abs(e[m]) <= eps * tst1:
                break
            m += 1
        if m > m0:
            for _ in range(60):
                g = d[m0]
                p = (d[m0 + 1] - g) / (2.0 * e[m0])
                r = math.sqrt(p * p + 1.0)
                if p < 0:
                    r = -r
                d[m0] = e[m0] / (p + r)
                d[m0 + 1] = e[m0] * (p + r)
                dl1 = d[m0 + 1]
                h = g - d[m0]
                for i in range(m0 + 2, n):
                    d[i] -= h
                f += h
                p = d[m]
                c = 1.0
                c2 = c
                c3 = c
                el1 = e[m0 + 1]
                s = 0.0
                s2 = 0.0
                for i in range(m - 1, m0 - 1, -1):
                    c3 = c2
                    c2 = c
                    s2 = s
                    g = c * e[i]
                    h = c * p
                    r = math.sqrt(p * p + e[i] * e[i])
                    e[i + 1] = s * r
                    s = e[i] / r
                    c = p / r
                    p = c * d[i] - s * g
                    d[i + 1] = h + s * (c * g + s * d[i])
                    wi = w[i]
                    wi1 = w[i + 1]
                    for k in range(n):
                        h = wi1[k]
                        wi1[k] = s * wi[k] + c * h
                        wi[k] = c * wi[k] - s * h
                p = -s * s2 * c3 * el1 * e[m0] / dl1
                e[m0] = s * p
                d[m0] = c * p
                if abs(e[m0]) <= eps * tst1:
                    break
        d[m0] = d[m0] + f
        e[m0] = 0.0
