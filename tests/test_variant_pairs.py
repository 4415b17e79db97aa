"""Variants against the configuration they vary, paired by seed (report's variant_pairs)."""

import math

import numpy as np
import pandas as pd
import pytest

from formation_bench.analysis.comparison import ReportError, analyse
from formation_bench.analysis.variant_pairs import (
    pair_table,
    to_markdown,
    variant_kind,
    variant_pairs,
)


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


def test_tuned_variants_pair_with_their_base_and_the_longest_suffix_wins():
    levels = ["pso", "pso-tuned", "pso-tuned-loop", "pso-warm", "pso-warm-tuned", "de-tuned-loop"]
    expected = [
        ("pso-tuned", "pso"),
        ("pso-tuned-loop", "pso"),
        ("pso-warm", "pso"),
        ("pso-warm-tuned", "pso-warm"),
    ]
    assert variant_pairs(levels) == expected
    # whichever order the suffixes are declared in: -tuned-loop is not a -loop of pso-tuned
    assert variant_pairs(levels, ("-tuned", "-warm", "-tuned-loop", "-loop")) == expected
    assert variant_kind("pso-tuned-loop", ("-loop", "-tuned-loop")) == "-tuned-loop"
    assert variant_kind("-tuned") is None  # a suffix alone names no variant


def test_each_kind_of_variant_is_its_own_holm_family_and_the_text_names_the_kinds():
    seeds = np.arange(12, dtype=float)
    frame = pd.concat(
        [
            # differences of distinct sizes: no ties, Wilcoxon's exact p
            _runs("pso", seeds + 100.0),
            _runs("pso-warm", 1.1 * seeds),
            _runs("pso-tuned", 1.2 * seeds),
            _runs("pso-tuned-loop", 1.3 * seeds + 200.0),
        ]
    )
    table = pair_table(frame, metrics=("steady_state_cost",)).set_index("variant")
    assert table.loc["pso-tuned", "kind"] == "tuned against default"
    assert table.loc["pso-tuned-loop", "kind"] == "tuned for the loop against default"
    # one pair per kind: each keeps its own p (Holm over one test), 2 / 2^12
    assert table["p_holm"].tolist() == pytest.approx([2.0 / 2**12] * 3)
    assert table.loc["pso-tuned-loop", "a12"] == 1.0
    text = to_markdown(pair_table(frame, metrics=("steady_state_cost",)))
    assert "`<name>-warm`: part of the population started around the warm start" in text
    assert "`<name>-tuned`: settings tuned per solve" in text
    assert "`<name>-tuned-loop`: settings tuned on a closed-loop metric" in text
    assert "Holm-adjusted over the pairs of one kind of variant in the block and metric" in text
    # warm variants alone: the text reads as it always did
    warm = to_markdown(pair_table(frame[frame["optimizer"].isin(["pso", "pso-warm"])],
                                  metrics=("steady_state_cost",)))  # fmt: skip
    assert "Each `<name>-warm` variant against `<name>`, paired by seed." in warm
    assert "over the pairs of the block and metric;" in warm


ABLATION_TUNED = (
    "modified-bso",
    "modified-bso-no-chaos-replacement",
    "modified-bso-no-all-centre",
    "modified-bso-no-modifications",
)


def test_an_ablation_with_every_variant_tuned_pairs_each_and_takes_a_tuned_baseline():
    seeds = np.arange(10, dtype=float)
    frame = pd.concat(
        [
            # tuned 0.5 above the default; slopes distinct, so no paired differences tie
            _runs(name + s, (1 + 0.01 * (2 * k + t)) * seeds + 10.0 * k + 0.5 * t, trigger=on)
            for k, name in enumerate(ABLATION_TUNED)
            for t, s in enumerate(("", "-tuned"))
            for on in (True, False)
        ]
    )
    table = pair_table(frame, metrics=("steady_state_cost",))
    for trigger in ("on", "off"):
        pairs = table[table["trigger"] == trigger]
        assert sorted(zip(pairs["variant"], pairs["base"], strict=True)) == sorted(
            (f"{name}-tuned", name) for name in ABLATION_TUNED
        )
    report = analyse(frame, baseline=["modified-bso-tuned"], metrics=["steady_state_cost"])
    assert report.baselines == ("modified-bso-tuned",)
    tested = report.wilcoxon
    assert set(tested["baseline"]) == {"modified-bso-tuned"}
    assert len(tested) == 2 * 7  # per trigger, every other level against the tuned baseline
    with pytest.raises(ReportError, match="not a level of optimizer"):
        analyse(frame, baseline=["pso-tuned"], metrics=["steady_state_cost"])


def test_a_metric_no_run_of_a_level_has_shows_as_missing_with_its_count():
    seeds = np.arange(6, dtype=float)
    frame = pd.concat([_runs("pso", seeds + 100.0), _runs("pso-warm", seeds)])
    # no pso run settles: pivoting the block on the optimiser leaves it no column
    frame["settling_time_s"] = np.where(frame["optimizer"] == "pso", np.nan, 20.0 + frame["seed"])
    table = pair_table(frame, metrics=("steady_state_cost", "settling_time_s"))
    settling = table.set_index("metric").loc["settling_time_s"]
    assert settling["n_pairs"] == 0
    assert math.isnan(settling["p"]) and math.isnan(settling["a12"])
    # no pairs: each level's median over its own runs says which one has no value
    assert settling["variant_median"] == 22.5 and math.isnan(settling["base_median"])
    assert not bool(settling["significant"])
    # the other metric keeps its pairs and its exact p
    assert table.set_index("metric").loc["steady_state_cost", "p"] == pytest.approx(2.0 / 2**6)
    text = to_markdown(table)
    (row,) = [line for line in text.splitlines() if line.startswith("| pso-warm | pso | 6 |")]
    assert row.endswith("| 22.5 vs – (n 0), –, A12 – |"), row
    assert "– (n 0): no run of the configuration has a value" in text
