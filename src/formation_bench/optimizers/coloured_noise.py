"""Coloured (power-law) Gaussian noise over the stages of a plan, as a fixed linear map.

iCEM (Pinneri et al., "Sample-efficient cross-entropy method for real-time planning",
CoRL 2020) samples its action sequences with noise whose power spectrum over time falls as
``1 / f**beta``, drawn by the FFT method of Timmer & Koenig ("On generating power law noise",
A&A 300, 1995) as the ``colorednoise`` package implements it: for a series of ``h`` samples,
each frequency ``k`` of ``rfftfreq(h)`` gets a Gaussian amplitude of scale ``f_k**(-beta/2)``
(the frequencies below ``1/h``, i.e. the mean, get the scale of ``1/h``), real and imaginary
parts independent, the mean's (and, for even ``h``, the Nyquist frequency's) imaginary part
zero and its real part times sqrt(2); the inverse real FFT is the series.

That construction is linear in ``h`` standard normals, so it is a fixed ``(h, h)`` matrix
``M`` (:func:`noise_matrix`, built with numpy's FFT among a solve's settings, which the
optimiser keeps for the next solves over the same box), and a series is ``M z``.
Normal ``j`` of ``z`` feeds, in order, the real parts of frequencies ``0 .. h // 2``, then the
imaginary parts of ``1 .. (h - 1) // 2`` (``colorednoise`` draws all real parts, then all
imaginary parts, and zeroes the imaginary ones this leaves out).

**Normalisation.** Each stage has unit variance exactly: the rows of ``M`` have unit norm.
``colorednoise`` divides by a "theoretical" standard deviation that leaves out the mean's
term and counts the Nyquist term at a quarter of its weight, which matters for short series:
its output has standard deviation 1.18 at ``h = 5``, ``beta = 2`` (the paper scenario's
horizon); so the ``std`` of the sampling distribution is here the actual standard deviation.

The series is periodic, as every FFT method's: the first and the last stage correlate as
neighbours do (0.35 at ``h = 5``, ``beta = 2``).

``beta = 0`` (white noise) and ``h = 1`` give the identity: the standard normals themselves,
which is plain CEM (the FFT construction at ``beta = 0`` is an orthogonal transform of them,
white noise of the same distribution but not the same numbers).
"""

from __future__ import annotations

import functools

import numpy as np

from formation_bench.kernel_cache import njit


def power_law_scales(exponent: float, stages: int) -> np.ndarray:
    """``colorednoise``'s amplitude scale per frequency of ``rfftfreq(stages)``:
    ``f**(-exponent / 2)``, with the frequencies below ``1 / stages`` at that one's scale."""
    frequencies = np.fft.rfftfreq(stages)
    cutoff = 1.0 / stages
    return np.maximum(frequencies, cutoff) ** (-exponent / 2.0)


@functools.lru_cache(maxsize=32)
def _noise_matrix(exponent: float, stages: int) -> np.ndarray:
    if exponent == 0.0 or stages == 1:
        return np.eye(stages)
    scales = power_law_scales(exponent, stages)
    frequencies = stages // 2 + 1
    real_only = {0, frequencies - 1} if stages % 2 == 0 else {0}
    matrix = np.empty((stages, stages))
    for j in range(stages):
        spectrum = np.zeros(frequencies, dtype=np.complex128)
        if j < frequencies:
            spectrum[j] = scales[j] * (np.sqrt(2.0) if j in real_only else 1.0)
        else:
            k = j - frequencies + 1
            spectrum[k] = 1j * scales[k]
        matrix[:, j] = np.fft.irfft(spectrum, n=stages)
    matrix /= np.linalg.norm(matrix, axis=1, keepdims=True)
    matrix.flags.writeable = False
    return matrix


def noise_matrix(exponent: float, stages: int) -> np.ndarray:
    """The ``(stages, stages)`` matrix ``M``: ``M z`` is Gaussian ``1 / f**exponent`` noise
    with unit variance per stage for ``z`` standard normal (see the module docstring); a
    private writable copy."""
    if stages < 1:
        raise ValueError(f"a series needs at least one stage, got {stages}")
    return _noise_matrix(float(exponent), int(stages)).copy()


@njit(cache=True)
def coloured_normals(normals: np.ndarray, noise_matrix: np.ndarray) -> np.ndarray:
    """The rows of ``normals`` (``(m, D)``, each a stage-major ``(h, D / h)`` block of
    standard normals) made coloured over the stages: row ``j`` becomes ``M Z_j``, one series
    per channel."""
    m, d = normals.shape
    stages = noise_matrix.shape[0]
    channels = d // stages
    out = np.zeros((m, d))
    for j in range(m):
        for t in range(stages):
            for u in range(stages):
                weight = noise_matrix[t, u]
                for c in range(channels):
                    out[j, t * channels + c] += weight * normals[j, u * channels + c]
    return out
