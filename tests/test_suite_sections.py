"""The report sections of the swarm, robustness and obstacles suites.

On a fake results table (numbers drawn from a seeded Generator, so the statistics can be
checked against direct computations), then end to end on a tiny real sweep through
``formation-bench report``.
"""

import json

import numpy as np
import pandas as pd
import pytest

from formation_bench.analysis import cells, stats
from formation_bench.analysis import suite_sections as sections
from formation_bench.cli.main import main
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.mpc.scenario import get_scenario
from formation_bench.pipeline.spec import canonical_json, config_of

OPTIMIZERS = ("modified-bso", "pso", "de")
SCENARIOS = {
    # label: (registered name, overrides, shift of every error metric)
    "N3-complete": ("paper", {}, 0.0),
    "N5-complete": ("swarm-5", {}, 2.0),
    "N5-ring": ("swarm-5", {"graph": "ring"}, -1.0),
    "loss-0.3": ("paper", {"packet_loss": 0.3}, 3.0),
    "loss-0.1": ("paper", {"packet_loss": 0.1}, 1.0),
    "gust-1": ("paper", {"gust_std_m_s": 1.0}, 0.5),
    "obstacles-on": ("paper-obstacles", {}, 0.0),
    "obstacles-off": ("paper-obstacles", {"w_obstacle": 0.0, "w_collision": 0.0}, 0.0),
}


def fake_results(seeds: int = 5, labels=tuple(SCENARIOS)) -> pd.DataFrame:
    rng = np.random.default_rng(11)
    rows = []
    # what a stored row holds: the scenario it ran, every setting
    configs = {
        label: canonical_json(config_of(get_scenario(SCENARIOS[label][0], **SCENARIOS[label][1])))
        for label in labels
    }
    for label in labels:
        name, overrides, shift = SCENARIOS[label]
        for k, optimizer in enumerate(OPTIMIZERS):
            for seed in range(seeds):
                # the optimisers differ by k, the scenarios by shift: known orders
                error = 1.0 + shift + 0.3 * k + 0.1 * rng.random()
                rows.append(
                    {
                        "suite": "fake",
                        "scenario": label,
                        "scenario_name": name,
                        "scenario_overrides": json.dumps(overrides, sort_keys=True),
                        "scenario_config": configs[label],
                        "optimizer": optimizer,
                        "optimizer_name": optimizer,
                        "trigger": True,
                        "budget": "max_evaluations=1200",
                        "seed": seed,
                        "tracking_error_max_m": error,
                        "distance_error_rms_m": error / 10,
                        "distance_error_max_m_max": error / 5,
                        "solves_total": int(rng.integers(200, 300)),
                        "collisions": int(rng.integers(0, 3)),
                        "collision_time_s": float(rng.integers(0, 3)) * 0.2,
                        "obstacle_intrusions": int("on" not in label) * int(rng.integers(1, 3)),
                        "obstacle_time_s": 0.2 * int("on" not in label),
                        "min_separation_m": 5.0 - error,
                        "solve_time_median_s": 1e-3 * (1 + k + rng.random()),
                    }
                )
    return pd.DataFrame(rows)


def by_name(found):
    return {s.name: s for s in found}


@pytest.fixture(scope="module")
def five():
    """The sections of the fake table with 5 seeds, and the table."""
    runs = fake_results()
    return by_name(sections.sections(runs)), runs


@pytest.fixture(scope="module")
def ten():
    """The sections of the fake table with 10 seeds, and the table."""
    runs = fake_results(seeds=10)
    return by_name(sections.sections(runs)), runs


def test_each_section_applies_to_the_runs_it_compares(five):
    found, _ = five
    assert set(found) == {"swarm", "robustness", "obstacles"}
    assert set(found["swarm"].runs["scenario"]) == {"N3-complete", "N5-complete", "N5-ring"}
    robustness = {"N3-complete", "loss-0.3", "loss-0.1", "gust-1"}
    assert set(found["robustness"].runs["scenario"]) == robustness
    assert set(found["obstacles"].runs["scenario"]) == {"obstacles-on", "obstacles-off"}
    # the paper scenario alone gets no section
    assert sections.sections(fake_results(labels=("N3-complete",))) == []


def test_scenario_columns_read_the_scenario_not_the_label():
    frame = sections.scenario_columns(fake_results()).drop_duplicates("scenario")
    frame = frame.set_index("scenario")
    assert frame.loc["N5-ring", "n_uav"] == 5 and frame.loc["N5-ring", "graph"] == "ring"
    assert frame.loc["loss-0.3", "family"] == "packet loss"
    assert frame.loc["gust-1", "family"] == "wind"
    assert frame.loc["obstacles-on", "penalties"] == "obstacle + collision"
    assert frame.loc["obstacles-off", "penalties"] == "off"
    # levels: nominal first, then the families in their order, the mildest level first
    order = frame["level_order"].sort_values().index.tolist()
    assert order.index("N3-complete") < order.index("gust-1") < order.index("loss-0.1")
    assert order.index("loss-0.1") < order.index("loss-0.3")


def test_swarm_medians_intervals_and_tests_match_direct_computation(five):
    found, runs = five
    swarm = found["swarm"]
    table = swarm.table.set_index(["scenario", "optimizer", "metric"])
    metric = "tracking_error_max_m"
    for scenario in ("N5-ring", "N3-complete"):
        for optimizer in OPTIMIZERS:
            values = runs[(runs["scenario"] == scenario) & (runs["optimizer"] == optimizer)]
            row = table.loc[(scenario, optimizer, metric)]
            assert row["median"] == np.median(values[metric])
            assert values[metric].min() <= row["ci_low"] <= row["median"] <= row["ci_high"]
    # the ring against the complete graph at N = 5, same optimiser
    ring = runs[(runs["scenario"] == "N5-ring") & (runs["optimizer"] == "pso")][metric]
    complete = runs[(runs["scenario"] == "N5-complete") & (runs["optimizer"] == "pso")][metric]
    row = table.loc[("N5-ring", "pso", metric)]
    assert row["condition_baseline"] == "N5-complete"
    assert row["condition_a12"] == stats.a12(ring.to_numpy(), complete.to_numpy()) == 0.0
    assert np.isnan(table.loc[("N3-complete", "pso", metric), "condition_a12"])
    # the optimisers: ranks 1..3 within every scenario, in the order the data were made
    ranks = swarm.table[swarm.table["metric"] == metric].pivot_table(
        index="scenario", columns="optimizer", values="average_rank"
    )
    assert (ranks.sum(axis=1) == 6.0).all()
    assert (ranks[list(OPTIMIZERS)].to_numpy() == [1.0, 2.0, 3.0]).all()


def _table_lines(text: str, heading: str) -> list[str]:
    """The table rows of the block under ``heading`` (up to the next heading)."""
    after = text.split(heading + "\n", 1)[1].split("\n### ", 1)[0]
    return [line for line in after.splitlines() if line.startswith("|")]


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip("|").split("|")]


HEADER = "| optimizer | tracking error max after the settle time (m) |"


@pytest.mark.slow
def test_swarm_one_table_per_cell_with_metric_columns_and_an_overall_ranking(five, ten):
    swarm = five[0]["swarm"]
    text = swarm.markdown
    headings = [line for line in text.splitlines() if line.startswith("### ")]
    assert headings == [
        "### N = 3, complete graph",
        "### N = 5, complete graph",
        "### N = 5, ring graph against the complete graph",
        "### Ranking across all cells",
    ]
    # the optimisers are the rows, the metrics the columns, headed with their unit
    lines = _table_lines(text, "### N = 5, ring graph against the complete graph")
    assert lines[0].startswith(HEADER) and "| median solve time (ms) |" in lines[0]
    assert [_cells(line)[0] for line in lines[2:]] == ["modified-bso", "de", "pso"]
    assert "**" not in text and "against N" not in text  # no table per metric
    # a cell: the median against the complete graph's, A12 and the Holm mark of the table
    table = swarm.table.set_index(["scenario", "optimizer", "metric"])
    metric = "tracking_error_max_m"
    ring, complete = (
        table.loc[("N5-ring", "pso", metric)],
        table.loc[("N5-complete", "pso", metric)],
    )
    pso = next(line for line in lines if line.startswith("| pso |"))
    column = sections.metric_column(metric)
    assert _cells(pso)[1] == (
        f"{column.value(ring['median'])} vs {column.value(complete['median'])}, "
        f"A12 {ring['condition_a12']:.2f}"
    )
    assert "smallest two-sided Wilcoxon p is 0.0625" in text
    # the ranking across all cells: Friedman over (cell, seed) blocks, as computed directly
    runs = swarm.runs
    values = runs.pivot_table(
        index=["scenario", "seed"], columns="optimizer", values=metric, aggfunc="first"
    )
    direct = stats.friedman(values)
    ranking = _table_lines(text, "### Ranking across all cells")
    assert [_cells(line)[0] for line in ranking[2:]] == [
        "modified-bso",
        "de",
        "pso",
        "Friedman p (blocks)",
    ]
    assert _cells(ranking[-1])[1] == f"{sections.p_cell(direct.pvalue)} ({direct.n_blocks})"
    assert direct.n_blocks == 15  # 3 cells x 5 seeds
    de = next(line for line in ranking if line.startswith("| de |"))
    assert _cells(de)[1] == f"{direct.average_ranks['de']:.2f}"
    stored = swarm.ranking.set_index(["metric", "optimizer"])
    assert stored.loc[(metric, "pso"), "average_rank"] == direct.average_ranks["pso"]
    # enough seeds for a significant pair: no note, and the clear differences are marked
    swarm = ten[0]["swarm"]
    assert "smallest two-sided Wilcoxon p" not in swarm.markdown
    ring = _table_lines(swarm.markdown, "### N = 5, ring graph against the complete graph")
    assert all(_cells(line)[1].endswith("A12 0.00*") for line in ring[2:])


def _tables(text: str) -> list[list[list[str]]]:
    """The Markdown tables of ``text``, each as its rows of cells (the rule left out)."""
    found, current = [], []
    for line in [*text.splitlines(), ""]:
        if line.startswith("|"):
            if not line.startswith("|---"):
                current.append(_cells(line))
        elif current:
            found.append(current)
            current = []
    return found


def _by_place(text: str) -> dict[tuple[tuple[str, ...], str, int], str]:
    """Every metric cell of the tables of ``text`` by its row (the cells up to the optimiser),
    its column's header and how many such cells came before: what a split keeps."""
    found: dict[tuple[tuple[str, ...], str, int], str] = {}
    for head, *rows in _tables(text):
        lead = head.index("optimizer") + 1
        for row in rows:
            for name, cell in zip(head[lead:], row[lead:], strict=True):
                k = sum(1 for key in found if key[:2] == (tuple(row[:lead]), name))
                found[(tuple(row[:lead]), name, k)] = cell
    return found


def test_every_table_fits_the_page_and_a_narrower_page_splits_it(five, monkeypatch):
    def width(table: list[list[str]]) -> int:
        return sum(cells.column_width(column) for column in zip(*table, strict=True))

    found, runs = five
    texts = {name: section.markdown for name, section in found.items()}
    assert all(width(t) <= cells.TABLE_WIDTH for text in texts.values() for t in _tables(text))
    # on a page too narrow for them, the metrics continue in tables of the same rows, each
    # within the width where a column allows, every cell as it was
    monkeypatch.setattr(cells, "TABLE_WIDTH", 40)
    narrow = by_name(sections.sections(runs))
    for name, section in narrow.items():
        tables = _tables(section.markdown)
        assert len(tables) > len(_tables(texts[name]))
        for table in tables:
            lead = table[0].index("optimizer") + 1
            assert len(table[0]) == lead + 1 or width(table) <= 40
        assert _by_place(section.markdown) == _by_place(texts[name])
    block = narrow["swarm"].markdown.split("### N = 5, ring graph against the complete graph")[1]
    values = _tables(block.split("\n### ", 1)[0].split("Optimiser ranks", 1)[0])
    assert len(values) > 1
    assert all([row[0] for row in t[1:]] == ["modified-bso", "de", "pso"] for t in values)


def test_robustness_compares_every_level_with_the_nominal_run(ten):
    robustness = ten[0]["robustness"]
    table = robustness.table
    rows = table[(table["metric"] == "tracking_error_max_m") & (table["family"] != "nominal")]
    assert set(rows["condition_baseline"]) == {"N3-complete"}
    # every level is shifted up from the nominal: A12 = 1, Holm-adjusted p below 0.05
    assert (rows["condition_a12"] == 1.0).all() and rows["condition_significant"].all()
    assert (rows["condition_p_holm"] < 0.05).all()
    levels = ["N3-complete", "gust-1", "loss-0.1", "loss-0.3"]
    assert list(dict.fromkeys(table["scenario"])) == levels
    # one block per level, in that order, each with the optimisers as rows
    assert list(robustness.blocks) == [
        "### nominal N3-complete",
        "### wind gust-1 against nominal",
        "### packet loss loss-0.1 against nominal",
        "### packet loss loss-0.3 against nominal",
    ]
    lines = _table_lines(robustness.markdown, "### packet loss loss-0.3 against nominal")
    assert lines[0].startswith(HEADER)
    de = next(line for line in lines if line.startswith("| de |"))
    assert _cells(de)[1].endswith("A12 1.00*")
    # ranks per block: the block's Friedman p, with its seeds
    friedman = table[
        (table["scenario"] == "loss-0.3") & (table["metric"] == "tracking_error_max_m")
    ]
    last = next(line for line in lines if line.startswith("| Friedman p (seeds) |"))
    first = friedman.iloc[0]
    assert _cells(last)[1] == (
        f"{sections.p_cell(first['friedman_p'])} ({int(first['friedman_seeds'])})"
    )


def test_obstacles_compare_the_penalties_on_with_off(five):
    found, runs = five
    obstacles = found["obstacles"]
    table = obstacles.table.set_index(["scenario", "optimizer", "metric"])
    row = table.loc[("obstacles-on", "modified-bso", "obstacle_intrusions")]
    on = runs[(runs["scenario"] == "obstacles-on") & (runs["optimizer"] == "modified-bso")]
    off = runs[(runs["scenario"] == "obstacles-off") & (runs["optimizer"] == "modified-bso")]
    assert row["condition_baseline"] == "obstacles-off"
    assert row["condition_a12"] == stats.a12(
        on["obstacle_intrusions"].to_numpy(), off["obstacle_intrusions"].to_numpy()
    )
    assert row["median"] == 0
    off_median = table.loc[("obstacles-off", "modified-bso", "obstacle_intrusions"), "median"]
    assert off_median > 0
    # one table for the scenario: penalties on against off, a column per metric
    heading = "### paper-obstacles, 3 UAVs: penalties obstacle + collision against off"
    assert list(obstacles.blocks) == [heading]
    lines = _table_lines(obstacles.markdown, heading)
    assert lines[0].startswith("| optimizer | obstacle intrusions per run (count) |")
    bso = _cells(next(line for line in lines if line.startswith("| modified-bso |")))
    assert bso[1] == f"0 vs {off_median:.0f}, A12 {row['condition_a12']:.2f}"
    # the ranks with each penalty setting, the Friedman p of each
    assert any(line.startswith("| obstacle + collision | Friedman p (seeds) |") for line in lines)
    assert any(line.startswith("| off | Friedman p (seeds) |") for line in lines)
    # the notebook's per-metric excerpt still finds the section's tables
    assert heading in obstacles.markdown


def test_a_ranks_table_whose_every_rank_is_tied_is_one_line():
    runs = fake_results(labels=("obstacles-on", "obstacles-off"))
    # every optimiser equal on every metric in every seed: ties everywhere
    metrics = list(sections.OBSTACLE_METRICS)
    runs[metrics] = runs.groupby(["scenario", "seed"])[metrics].transform("first")
    obstacles = by_name(sections.sections(runs))["obstacles"]
    text = obstacles.markdown
    assert "Friedman p (seeds)" not in text
    assert "no ranks table. Every optimiser has the same average rank" in text
    ranks = obstacles.table["average_rank"].dropna()
    assert ranks.nunique() == 1


SUITE = """\
name = "tiny-scenarios"
seeds = 3
triggers = [true]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 2 }

[[optimizers]]
name = "pso"
overrides = { max_iterations = 2 }

[[scenarios]]
name = "paper"
label = "N3"
overrides = { n_steps = 10, settle_time_s = 1.0 }

[[scenarios]]
name = "swarm-5"
label = "N5-ring"
overrides = { n_steps = 10, settle_time_s = 1.0, graph = "ring" }

[[scenarios]]
name = "paper"
label = "loss-0.3"
overrides = { n_steps = 10, settle_time_s = 1.0, packet_loss = 0.3 }

[[scenarios]]
name = "paper-obstacles"
label = "obstacles-on"
overrides = { n_steps = 10, settle_time_s = 1.0 }

[[scenarios]]
name = "paper-obstacles"
label = "obstacles-off"
overrides = { n_steps = 10, settle_time_s = 1.0, w_obstacle = 0.0, w_collision = 0.0 }
"""


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny-scenarios")
    suite = parse_suite(SUITE, out / "tiny.toml")
    run_sweep(suite, out, jobs=1, progress=False, log=lambda _: None)
    return out


@pytest.mark.slow
def test_report_writes_the_sections_of_a_real_sweep(results, capsys):
    assert main(["report", str(results)]) == 0
    capsys.readouterr()
    folder = results / "report"
    report = (folder / "report.md").read_text()
    for name, heading in (
        ("swarm", "## Swarm: metrics against the number of UAVs"),
        ("robustness", "## Robustness: metrics against the disturbance level"),
        ("obstacles", "## Obstacles: penalties on and off"),
    ):
        section = (folder / f"{name}.md").read_text()
        assert section.startswith(heading) and heading in report
        table = pd.read_csv(folder / f"{name}.csv")
        assert {"median", "ci_low", "ci_high", "average_rank", "condition_a12"} <= set(table)
        assert (table["n"] == 3).all()
    swarm = pd.read_csv(folder / "swarm.csv")
    assert set(swarm["n_uav"]) == {3, 5} and set(swarm["graph"]) == {"complete", "ring"}
    ranking = pd.read_csv(folder / "swarm_ranking.csv")
    assert ranking["optimizer"].nunique() == 2 and (ranking["average_rank"] > 0).all()
    figures = folder / "figures"
    stems = [f"swarm_{m}" for m in sections.SWARM_METRICS]
    stems += [f"robustness_{m}" for m in sections.ROBUSTNESS_METRICS]
    for stem in [*stems, "obstacles_separation"]:
        assert (figures / f"{stem}.png").stat().st_size > 10_000


def test_the_robustness_sentence_compares_each_level_with_the_nominal_run_of_its_budget():
    from formation_bench.analysis import notebook as analysis

    runs = fake_results(labels=("N3-complete", "loss-0.3", "loss-0.1", "gust-1"))
    slower = runs.assign(
        budget="max_evaluations=600", tracking_error_max_m=runs["tracking_error_max_m"] + 5.0
    )
    section = analysis.scenario_section(pd.concat([runs, slower]), "robustness")
    text = analysis.robustness_sentence(section)
    rows = section.table[section.table["metric"] == "tracking_error_max_m"]
    medians = rows.set_index(["scenario", "optimizer", "budget"])["median"]
    worst = medians[("loss-0.3", "de", "max_evaluations=600")]
    nominal = medians[("N3-complete", "de", "max_evaluations=600")]
    assert f"{worst:.3g} against {nominal:.3g}" in text  # the +5 budget's own nominal run
    assert "18 of 18 (level, optimiser, trigger) cells" in text


def test_the_rank_note_marks_the_worst_where_higher_values_are_better(five):
    found, runs = five
    # where the separation is constant it is no column, and no rank is the worst
    level = runs.assign(min_separation_m=1.0)
    checked = set()
    for section in [*found.values(), *sections.sections(level)]:
        for heading, text in section.blocks.items():
            ranked = [
                line for line in text.splitlines() if line.startswith("Optimiser ranks within")
            ]
            if not ranked:
                continue
            header = next(
                line
                for line in text.splitlines()[text.splitlines().index(ranked[0]) :]
                if line.startswith("| ")
            )
            higher = "smallest separation of two UAVs" in header
            assert ("rank 1 is the worst on smallest separation" in ranked[0]) == higher, heading
            checked.add(higher)
    assert checked == {True, False}


def test_scenario_columns_read_the_stored_scenario_not_todays_registry():
    """A plugin's scenario (a name not registered here) is described from its stored settings,
    and a stored setting wins over today's registered value."""
    results = fake_results(seeds=1, labels=("N5-ring", "loss-0.3"))
    results["scenario_name"] = "a-plugin-scenario"
    results["scenario_overrides"] = "{}"
    frame = sections.scenario_columns(results).drop_duplicates("scenario").set_index("scenario")
    assert frame.loc["N5-ring", "n_uav"] == 5 and frame.loc["N5-ring", "graph"] == "ring"
    assert frame.loc["loss-0.3", "family"] == "packet loss"


def test_a_metric_constant_over_a_block_is_named_on_a_line_not_tabulated():
    runs = fake_results().assign(collisions=0)
    swarm = by_name(sections.sections(runs))["swarm"]
    for heading, text in swarm.blocks.items():
        assert "collisions per run = 0" in text, heading
        assert "collisions" not in swarm.block_columns[heading]
        assert "tracking_error_max_m" in swarm.block_columns[heading]
    assert "collisions per run (count)" not in swarm.markdown
    # the other metrics are headed with their unit, a time below a second in ms
    assert HEADER in swarm.markdown
    assert "| median solve time (ms) |" in swarm.markdown
