"""Shi's Brain Storm Optimization exactly as published (ICSI 2011), on the shared BSO operators.

Shi, Y. (2011). Brain Storm Optimization Algorithm. In: Advances in Swarm
Intelligence (ICSI 2011), LNCS 6728, pp. 303-309, Springer.

Per iteration, following the paper's steps:

2. **k-means** of the N ideas into m clusters (Lloyd's algorithm, started
   from m distinct members drawn at random), re-run every iteration;
3. the **best idea of each cluster is its centre**;
4. with probability **p_5a** (0.2) a randomly chosen centre is replaced by a
   **uniformly random point** of the box. The paper does not say whether
   that point is evaluated or enters the population; here it replaces the
   centre only as a *source of ideas* for this iteration: it is not
   evaluated and the population slot of the old centre keeps its idea;
5. every one of the N slots gets a new idea: with probability **p_6b** (0.8)
   from **one cluster chosen with probability proportional to its size**
   (p_6bi), its centre with probability **p_6biii** (0.4) or else a uniformly
   random member; otherwise from **two distinct clusters** chosen uniformly,
   both centres with probability **p_6c** (0.5) or else one random member of
   each, mixed as **r A + (1 - r) B** with r uniform in (0, 1) per idea;
6. the idea is moved by ``xi * N(0, 1)`` with an independent normal per
   dimension and ``xi = logsig((0.5 T_max - t) / k) * rand``, where ``rand`` is
   one uniform per idea and **k = 20**;
7. **slot-wise greedy selection**: the new idea replaces the idea in the same
   slot only when it is strictly better.

Where public implementations deviate (and this one does not): fixed groups of
consecutive indices instead of k-means, a cluster chosen at random instead of
by size, a greedy step that compares the new idea with itself and so always
accepts it, and 0.5 (A + B) instead of r A + (1 - r) B (all in mealpy's
``OriginalBSO``), one ``xi`` per iteration instead of one per idea and no
``xi`` at all for ideas from a random member (mealpy), or one normal value
added to every dimension (other implementations). ``docs/explanation/optimizers.md``
compares this implementation with mealpy's on BBOB functions.

The paper says nothing about ideas that leave the box; they are clipped
(``bound_handling``). The step ``N(0, 1)`` is in absolute units as published
(``step_scale = 1``, ``step_relative_to_range = False``); on a box as narrow as
the turn-rate bounds of the paper problem (+-0.25) that step is huge, which is
why the modified BSO scales it by the range.

Shi starts from N uniform ideas; here the warm start is one of them, as for every
population method. ``original-bso-warm``, not Shi's, draws a share of them around the warm
start (:class:`~formation_bench.optimizers.population.WarmStartInit`).

The random numbers of one iteration are laid out as in
:class:`~formation_bench.optimizers.modified_bso.ModifiedBSO` with all-centre weighting off
(:class:`~formation_bench.optimizers.bso_ops.BSODraws`), the random point taking the place of
the chaotic seed ``cr(0)``: with ``p_replace = 0`` and the same step settings the two produce
identical runs, which the tests use to show that the ablation without both modifications is
Shi's idea generation.

The iteration is written once, as the ask/tell kernels of
:mod:`~formation_bench.optimizers.original_bso_kernels`, which both solve loops of
:mod:`~formation_bench.optimizers.ask_tell` drive.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.optimizers.ask_tell import AskTellOptimizer, DrawPlan, Kernels
from formation_bench.optimizers.base import Bounds
from formation_bench.optimizers.original_bso_kernels import (
    BSOState,
    ShiConfig,
    shi_ask,
    shi_iterate,
    shi_tell,
)
from formation_bench.optimizers.population import WarmStartInit
from formation_bench.optimizers.registry import register


# WarmStartInit leads the bases because dataclass fields follow the reversed MRO: its settings
# then come after the method's own, whose positions and listing order stay as they were
@dataclass(frozen=True)
class OriginalBSO(WarmStartInit, ShiConfig, AskTellOptimizer):
    """Shi's (2011) BSO: probabilities and slope as published; N and T_max for ~1300 evaluations.

    The settings are those of :class:`~formation_bench.optimizers.original_bso_kernels.ShiConfig`
    and, for the initial ideas, :class:`~formation_bench.optimizers.population.WarmStartInit`.
    """

    compile_cpu_s = 10.0
    kernels = Kernels(shi_ask, shi_tell, shi_iterate)

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return self.shi_settings(bounds, t_max)

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> BSOState:
        return BSOState(points, costs, 0)

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        return DrawPlan(self.uniforms_per_step(n, d), (n, d))

    def result_info(self, state: BSOState) -> dict[str, Any]:
        return {"random_replacements": state.replacements}


WARM_START_SHARE = 0.9
"""``warm_start_share`` of ``original-bso-warm``: chosen with the spread on the instance
library's validation split (docs/explanation/optimizers.md, "Initial population around the
warm start")."""
WARM_START_SPREAD = 0.005
"""``warm_start_spread`` of ``original-bso-warm``, chosen with the share."""

register(
    "original-bso",
    OriginalBSO(),
    "Shi's (2011) BSO as published: k-means, random-point centre replacement, logsig N(0,1) step",
)
register(
    "original-bso-warm",
    OriginalBSO(warm_start_share=WARM_START_SHARE, warm_start_spread=WARM_START_SPREAD),
    f"original-bso with {WARM_START_SHARE:.0%} of the initial ideas drawn around the warm "
    f"start (std {WARM_START_SPREAD:g} x range), the rest uniform; not Shi's start",
)
register(
    "original-bso-range-step",
    OriginalBSO(step_scale=0.1, step_relative_to_range=True),
    "Shi's BSO with the modified BSO's step (0.1 x range instead of N(0, 1))",
)
