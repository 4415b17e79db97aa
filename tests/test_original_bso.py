"""Shi's original BSO and the chaotic-local-search BSO built on it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import BOX, D, sphere
from test_modified_bso import iterations_by_hand

from formation_bench.optimizers import (
    OPTIMIZERS,
    Bounds,
    Budget,
    ChaoticLocalSearchBSO,
    ModifiedBSO,
    OptimizeResult,
    OriginalBSO,
    get_optimizer,
)
from formation_bench.optimizers.chaos import ChaoticMap
from formation_bench.optimizers.cls_bso import local_radius
from formation_bench.optimizers.original_bso_kernels import replace_centre


def shifted_rastrigin(x: np.ndarray) -> np.ndarray:
    z = x - np.linspace(-2.0, 2.0, x.shape[1])
    return 10.0 * z.shape[1] + (z * z - 10.0 * np.cos(2.0 * np.pi * z)).sum(axis=1)


def run(opt, f=sphere, seed: int = 0, **kw) -> OptimizeResult:
    return opt.minimize(f, kw.pop("bounds", BOX), np.random.default_rng(seed), **kw)


def same_run(a: OptimizeResult, b: OptimizeResult) -> bool:
    return (
        np.array_equal(a.x, b.x)
        and a.fun == b.fun
        and np.array_equal(a.history_nfev, b.history_nfev)
        and np.array_equal(a.history_fun, b.history_fun)
    )


# --- the ablation without both modifications is Shi's idea generation ---------------------------


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("f", [sphere, shifted_rastrigin])
def test_no_modifications_ablation_is_shis_bso_without_the_random_centre(seed: int, f) -> None:
    """Same random numbers, same ideas: the two runs agree bit for bit."""
    ablation = get_optimizer("modified-bso-no-modifications")
    shi = OriginalBSO(p_replace=0.0, step_scale=0.1, step_relative_to_range=True)
    assert same_run(run(ablation, f, seed), run(shi, f, seed))


def test_the_random_centre_replacement_is_what_remains_different() -> None:
    ablation = get_optimizer("modified-bso-no-modifications")
    shi = get_optimizer("original-bso-range-step")
    assert not same_run(run(ablation, seed=1), run(shi, seed=1))
    res = run(OriginalBSO(p_replace=1.0), seed=1)
    assert res.info["random_replacements"] == res.nit == 40
    assert res.nfev == 30 * 41  # the random centre is not evaluated


def test_replace_centre_appends_the_point_and_keeps_the_members() -> None:
    population = np.arange(12.0).reshape(6, 2)
    centre_index = np.array([4, -1, 1], dtype=np.int64)  # cluster 1 is empty
    point = np.array([-7.0, -8.0])
    sources, centres = replace_centre(population, centre_index, 0.99, point)  # last non-empty
    np.testing.assert_array_equal(sources[:6], population)
    np.testing.assert_array_equal(sources[6], point)
    np.testing.assert_array_equal(centres, [4, -1, 6])
    _, centres = replace_centre(population, centre_index, 0.0, point)
    np.testing.assert_array_equal(centres, [6, -1, 1])
    np.testing.assert_array_equal(centre_index, [4, -1, 1])  # input untouched


def test_published_defaults() -> None:
    opt = get_optimizer("original-bso")
    assert isinstance(opt, OriginalBSO)
    assert (opt.p_replace, opt.p_one_cluster, opt.p_one_centre, opt.p_two_centres) == (
        0.2,
        0.8,
        0.4,
        0.5,
    )
    assert opt.slope == 20.0 and opt.step_scale == 1.0 and not opt.step_relative_to_range
    assert opt.default_budget == Budget(max_iterations=40)


@pytest.mark.parametrize("seed", range(3))
def test_original_bso_optimises(seed: int) -> None:
    res = run(OriginalBSO(), seed=seed)
    assert res.nit == 40 and res.nfev == 1230
    assert res.fun < 0.5
    assert np.all(np.diff(res.history_fun) <= 0)
    budget = Budget(max_evaluations=3000)
    box = Bounds(np.full(D, -5.12), np.full(D, 5.12))
    assert run(OriginalBSO(), shifted_rastrigin, seed, bounds=box, budget=budget).fun < 60.0


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("population_size", 1),
        ("n_clusters", 31),
        ("max_iterations", -1),
        ("slope", 0.0),
        ("p_replace", 1.5),
        ("p_one_cluster", -0.1),
        ("p_one_centre", math.nan),
        ("p_two_centres", "half"),
        ("step_scale", 0.0),
        ("step_relative_to_range", 1),
        ("bound_handling", "wrap"),
        ("kmeans_max_iter", 0),
    ],
)
def test_invalid_config_names_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"OriginalBSO\.{field} must"):
        OriginalBSO(**{field: value})


# --- chaotic local search BSO -----------------------------------------------------------------


def test_cls_bso_budget_and_info() -> None:
    opt = get_optimizer("cls-bso")
    assert isinstance(opt, ChaoticLocalSearchBSO)
    assert opt.evaluations_per_step() == 30 and opt.initial_evaluations() == 25
    res = run(opt, seed=2)
    assert res.nfev == 25 + 40 * 30 and res.nit == 40
    assert 0 < res.info["local_search_improvements"] <= 40
    assert run(opt, budget=Budget(max_evaluations=57)).nfev == 57  # 25 + 30, then 2 ideas


def test_cls_bso_local_search_helps_late_convergence() -> None:
    # same BSO, with and without the local search points (same number of evaluations)
    with_cls = [run(ChaoticLocalSearchBSO(), seed=s).fun for s in range(5)]
    without = [run(OriginalBSO(population_size=30), seed=s).fun for s in range(5)]
    assert np.median(with_cls) < np.median(without)


def test_cls_bso_map_and_radius_matter() -> None:
    base = run(ChaoticLocalSearchBSO(), seed=3)
    assert not same_run(base, run(ChaoticLocalSearchBSO(local_map=ChaoticMap.TENT), seed=3))
    assert not same_run(base, run(ChaoticLocalSearchBSO(local_radius_start=0.5), seed=3))


def test_local_radius_schedule() -> None:
    assert local_radius(0.1, 0.001, 1, 40) == pytest.approx(0.1)
    assert local_radius(0.1, 0.001, 40, 40) == pytest.approx(0.001)
    assert local_radius(0.1, 0.001, 20, 39) == pytest.approx(0.01)
    assert local_radius(0.1, 0.001, 5, 1) == pytest.approx(0.1)


@pytest.mark.parametrize(
    ("field", "value"),
    [("n_local", 0), ("local_radius_start", 0.0), ("local_radius_end", 0.2), ("local_map", "x")],
)
def test_cls_invalid_config_names_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"ChaoticLocalSearchBSO\.{field} must"):
        ChaoticLocalSearchBSO(**{field: value})


# --- registry -----------------------------------------------------------------------------------


def test_modified_bso_with_every_other_map_is_registered() -> None:
    for map_ in ChaoticMap:
        name = (
            "modified-bso" if map_ is ChaoticMap.LOGISTIC else f"modified-bso-{map_.name.lower()}"
        )
        opt = OPTIMIZERS[name].optimizer
        assert isinstance(opt, ModifiedBSO)
        assert opt.replacement_map is map_ and opt.weight_map is map_
        assert opt == ModifiedBSO(replacement_map=map_, weight_map=map_)


@pytest.mark.parametrize("name", ["original-bso", "original-bso-range-step", "cls-bso"])
def test_after_each_iteration_the_population_keeps_the_best_point(name: str) -> None:
    """Every member's cost is its own, no slot gets worse, and the best member is the best
    point found."""
    optimizer = get_optimizer(name)
    runs = list(iterations_by_hand(optimizer, shifted_rastrigin, 12, seed=2))
    previous = None
    for state, _, rounds in runs:
        assert [last for _, last in rounds] == [True]
        np.testing.assert_array_equal(shifted_rastrigin(state.x), state.f)
        assert previous is None or np.all(state.f <= previous)
        previous = state.f
    state, counter, _ = runs[-1]
    assert state.f.min() == counter.best_f
    np.testing.assert_array_equal(state.x[np.argmin(state.f)], counter.best_x)


def test_cls_bso_asks_for_the_ideas_then_the_local_points_around_the_best() -> None:
    optimizer = ChaoticLocalSearchBSO(n_local=4, local_radius_start=0.01, local_radius_end=0.01)
    radius = 0.01 * BOX.width
    best = None
    for state, _, rounds in iterations_by_hand(optimizer, sphere, 3, seed=5):
        ((candidates, _),) = rounds
        assert candidates.shape == (25 + 4, D)
        if best is not None:  # the local points lie around the best member asked from
            assert np.all(np.abs(candidates[25:] - best) <= radius)
            assert np.all(np.abs(candidates[25:] - best) > 0.0)
        best = state.x[np.argmin(state.f)]


def test_cls_bso_with_resample_bound_handling_stays_in_the_box() -> None:
    from formation_bench.optimizers.bound_handling import BoundHandling

    optimizer = ChaoticLocalSearchBSO(bound_handling=BoundHandling.RESAMPLE, local_radius_start=1.0)
    assert optimizer.has_compiled_loop()
    recorder = []

    def recording(x: np.ndarray) -> np.ndarray:
        recorder.append(x.copy())
        return sphere(x - 4.9)

    res = run(optimizer, recording, seed=4, budget=Budget(max_iterations=8))
    points = np.vstack(recorder)
    assert np.all(points >= BOX.lower) and np.all(points <= BOX.upper)
    assert res.nfev == 25 + 8 * 30
