"""Kernels of the sampling-based MPC optimisers (:mod:`.mppi`, :mod:`.predictive_sampling`).

Both perturb a *nominal plan*, a stage-major vector ``[c_1, ..., c_C]`` per stage for ``C =
plan_channels`` channels (the MPC's plan is ``[a_1, omega_1, ..., a_B, omega_B]``, C = 2), with
Gaussian noise of one standard deviation per channel, as their sources perturb a control
sequence with one covariance over the horizon. The plan structure is an optimiser setting
(:class:`PlanShape`), not knowledge of the MPC. Samples are clipped to the box, which the
sources leave open (MJPC clamps to the control range; MPPI's papers leave it to the model).

The pure update rules live here as compiled functions of plain arrays, so that a test can
drive them with fixed random numbers: the clipped samples (:func:`plan_samples`), and MPPI's
temperature (:func:`temperature_of`), path-integral weights (:func:`path_integral_weights`)
and smoothing along the stages (:func:`smooth_stages`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from formation_bench.fields import setting
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.base import Bounds


@dataclass(frozen=True)
class PlanShape:
    """The plan's structure, a setting of a sampling method."""

    plan_channels: int = setting(
        2, low=1,
        doc="Values per stage of a stage-major plan; the decision vector's length must be a "
        "multiple of it",
    )  # fmt: skip

    def stages(self, dim: int) -> int:
        """Stages of a plan of ``dim`` values; ValueError naming the field if ``dim`` is not a
        multiple of ``plan_channels``."""
        if dim % self.plan_channels:
            raise ValueError(
                f"{type(self).__name__}.plan_channels = {self.plan_channels} must divide the "
                f"decision vector's length, got dimension {dim}"
            )
        return dim // self.plan_channels

    def stage_noise(self, bounds: Bounds, noise_std: float) -> np.ndarray:
        """Standard deviation per coordinate: ``noise_std`` times the channel's range, the mean
        of its stages' widths (the width itself when the bounds repeat per stage, as the
        MPC's do), the same for every stage of a channel."""
        stages = self.stages(bounds.dim)
        channel_width = bounds.width.reshape(stages, self.plan_channels).mean(axis=0)
        return np.ascontiguousarray(np.tile(noise_std * channel_width, stages))


class NominalStart:
    """The start of a sampling method: the nominal plan alone, evaluated first."""

    def initial_evaluations(self) -> int:
        return 1

    def initial_points(
        self, bounds: Bounds, rng: np.random.Generator, x0: np.ndarray | None
    ) -> np.ndarray:
        """The nominal alone: ``x0``, else the box centre (no random numbers drawn)."""
        start = (bounds.lower + bounds.upper) / 2.0 if x0 is None else x0
        return np.array(start, dtype=np.float64)[None]


def check_window(owner: str, name: str, value: object) -> int:
    """``value`` if it is 0, 1 or an odd integer >= 3 (a centred window), else ValueError."""
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)
    if ok and (value in (0, 1) or (value >= 3 and value % 2 == 1)):  # type: ignore[operator]
        return int(value)  # type: ignore[arg-type]
    raise ValueError(f"{owner}.{name} must be 0, 1 or an odd integer >= 3, got {value!r}")


class TemperatureScale(IntEnum):
    """What MPPI's ``temperature`` is relative to (:func:`temperature_of`)."""

    ABSOLUTE = 0
    """lambda = temperature, in cost units (the papers')."""
    SPREAD = 1
    """lambda = temperature (max J - min J) over the iteration's finite costs."""
    MAD = 2
    """lambda = temperature median |J - median J| over the iteration's finite costs."""


@njit(cache=True)
def plan_samples(
    nominal: np.ndarray, normals: np.ndarray, noise: np.ndarray, lower: np.ndarray,
    upper: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """``clip(nominal + noise * normals)`` row by row, ``(K, D)`` for ``(K, D)`` normals."""
    k, d = normals.shape
    samples = np.empty((k, d))
    for i in range(k):
        for c in range(d):
            samples[i, c] = min(max(nominal[c] + noise[c] * normals[i, c], lower[c]), upper[c])
    return samples


@njit(cache=True)
def temperature_of(costs: np.ndarray, temperature: float, temperature_scale: int) -> float:
    """lambda of an iteration's ``costs`` (``temperature_scale`` a :class:`TemperatureScale`);
    non-finite costs are left out, and a relative lambda is 0 with fewer than two distinct
    finite costs."""
    if temperature_scale == TemperatureScale.ABSOLUTE:
        return temperature
    finite = costs[np.isfinite(costs)]
    if finite.shape[0] == 0:
        return 0.0
    if temperature_scale == TemperatureScale.SPREAD:
        return temperature * (finite.max() - finite.min())
    return temperature * np.median(np.abs(finite - np.median(finite)))


@njit(cache=True)
def path_integral_weights(scores: np.ndarray, costs: np.ndarray, lam: float) -> np.ndarray:
    """``w_k = exp(-(S_k - min S) / lambda) / eta`` over the samples of finite cost ``costs``
    (``S`` = ``scores``, the costs with any control term); 0 for the others, and all 0 when
    no cost is finite. At ``lambda = 0``, the limit: equal weights on the least costs."""
    k = scores.shape[0]
    weights = np.zeros(k)
    rho = math.inf
    least = math.inf
    for i in range(k):
        if math.isfinite(costs[i]):
            rho = min(rho, scores[i])
            least = min(least, costs[i])
    if not math.isfinite(least):
        return weights
    for i in range(k):
        if not math.isfinite(costs[i]):
            continue
        if lam > 0.0:
            weights[i] = math.exp(-(scores[i] - rho) / lam)
        elif costs[i] == least:
            weights[i] = 1.0
    return weights / weights.sum()


@njit(cache=True)
def smooth_stages(values: np.ndarray, stages: int, smoothing_window: int) -> np.ndarray:
    """A centred moving average of ``smoothing_window`` stages of a stage-major plan, channel
    by channel, the window cut at the plan's ends (the mean of the stages there); a copy for a
    window below 3."""
    if smoothing_window < 3:
        return values.copy()
    channels = values.shape[0] // stages
    half = smoothing_window // 2
    out = np.empty_like(values)
    for j in range(stages):
        first, last = max(j - half, 0), min(j + half, stages - 1)
        for c in range(channels):
            total = 0.0
            for i in range(first, last + 1):
                total += values[i * channels + c]
            out[j * channels + c] = total / (last - first + 1)
    return out
