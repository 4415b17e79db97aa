"""Variants against the configuration they vary, paired by seed (report's variant_pairs)."""

import math

import numpy as np
import pandas as pd
import pytest

from formation_bench.analysis.variant_pairs import pair_table, to_markdown, variant_pairs


def _runs(optimizer: str, values: np.ndarray, trigger: bool = True) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "optimizer": optimizer,
            "scenario": "paper",
            "trigger": trigger,
            "budget": "max_evaluations=1200",
            "seed": np.arange(len(values)),
            "steady_state_cost": values,
        }
    )


def test_pairs_are_found_by_name_and_only_with_their_base():
    levels = ["de", "de-warm", "modified-bso-warm", "pso", "pso-warm"]
    assert variant_pairs(levels) == [("de-warm", "de"), ("pso-warm", "pso")]


def test_a_variant_lower_on_every_seed_gives_the_exact_wilcoxon_p_and_a12_zero():
    seeds = np.arange(12, dtype=float)
    frame = pd.concat(
        [
            _runs("pso", seeds + 100.0),
            _runs("pso-warm", seeds),
            _runs("de", seeds * 2.0),
            _runs("de-warm", seeds * 2.0),  # identical: no evidence of a difference
        ]
    )
    table = pair_table(frame, metrics=("steady_state_cost",)).set_index("variant")
    pso = table.loc["pso-warm"]
    # 12 negative differences: the exact two-sided p is 2 / 2^12
    assert pso["p"] == pytest.approx(2.0 / 2**12)
    assert pso["p_holm"] == pytest.approx(2 * 2.0 / 2**12)  # 2 pairs, smallest p times 2
    assert pso["a12"] == 0.0 and pso["median_difference"] == -100.0
    assert pso["variant_median"] == 5.5 and pso["base_median"] == 105.5
    assert bool(pso["significant"])
    de = table.loc["de-warm"]
    assert de["p"] == 1.0 and de["a12"] == 0.5 and not bool(de["significant"])
    text = to_markdown(pair_table(frame, metrics=("steady_state_cost",)))
    # one table for the block: the pairs as rows, the metric as a column with its unit
    assert text.count("| variant | base | pairs |") == 1
    assert (
        "| variant | base | pairs | steady-state cost, eq. (11) after the settle time (m² s) |"
        in text
    )
    pso_row = next(line for line in text.splitlines() if line.startswith("| pso-warm | pso | 12 |"))
    assert pso_row == "| pso-warm | pso | 12 | 5.50 vs 106, 9.77e-04 *, A12 0.00 |", pso_row


def test_no_pair_means_no_table():
    frame = pd.concat([_runs("pso", np.arange(5.0)), _runs("de", np.arange(5.0))])
    table = pair_table(frame, metrics=("steady_state_cost",))
    assert table.empty and to_markdown(table) == ""


def test_blocks_are_compared_apart():
    frame = pd.concat(
        [
            _runs("pso", np.arange(6.0), trigger=True),
            _runs("pso-warm", np.arange(6.0) + 1.0, trigger=True),
            _runs("pso", np.arange(6.0), trigger=False),
            _runs("pso-warm", np.arange(6.0) - 1.0, trigger=False),
        ]
    )
    table = pair_table(frame, metrics=("steady_state_cost",)).set_index("trigger")
    assert table.loc["on", "median_difference"] == 1.0
    assert table.loc["off", "median_difference"] == -1.0
    assert not math.isnan(table.loc["off", "p"])
