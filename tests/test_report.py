"""``formation-bench report`` end to end on a small sweep."""

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

from formation_bench.analysis import cells
from formation_bench.analysis.cells import (
    COLUMN_PADDING,
    TABLE_WIDTH,
    Grid,
    column_width,
    fitted,
    metric_column,
    split_columns,
)
from formation_bench.analysis.comparison import analyse
from formation_bench.analysis.report import to_markdown
from formation_bench.analysis.results_page import (
    FINDINGS_END,
    FINDINGS_START,
    write_results_page,
)
from formation_bench.cli.main import main
from formation_bench.experiments.store import load_results
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.mpc.metrics import (
    Better,
    Per,
    column_label,
    headline_metrics,
    metric_infos,
)

SUITE = """\
name = "small"
seeds = 5
triggers = [true, false]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 3 }

[[optimizers]]
name = "modified-bso-no-all-centre"
label = "no-all-centre"
overrides = { max_iterations = 3 }

[[optimizers]]
name = "modified-bso-no-modifications"
label = "no-modifications"
overrides = { max_iterations = 3 }

[[scenarios]]
name = "paper"
overrides = { n_steps = 12, settle_time_s = 1.0 }
"""


def tables_in(text: str) -> list[list[list[str]]]:
    """The Markdown tables of ``text``, each as its rows of cells (the rule left out)."""
    found: list[list[list[str]]] = []
    current: list[list[str]] = []
    for line in [*text.splitlines(), ""]:
        if line.startswith("|"):
            if not line.startswith("|---"):
                current.append([cell.strip() for cell in line.strip().strip("|").split(" | ")])
        elif current:
            found.append(current)
            current = []
    return found


def estimated_width(table: list[list[str]]) -> int:
    """The narrowest ``table`` can be, in characters (:func:`column_width` of each column)."""
    return sum(column_width(column) for column in zip(*table, strict=True))


def cells_by_place(text: str) -> dict[tuple[str, str, str, int], str]:
    """Every body cell of the tables of ``text`` by the table's kind (its first header), its
    row's label, its column's header and how many tables of that kind and place came
    before (a block's tables in order): what a layout change must keep, the runs of a row
    repeated beside each part of a split table counted once."""
    found: dict[tuple[str, str, str, int], str] = {}
    for table in tables_in(text):
        head, *rows = table
        for row in rows:
            for name, cell in zip(head[1:], row[1:], strict=True):
                if name == "runs" and (head[0], row[0], name, 0) in found:
                    continue
                k = 0
                while (head[0], row[0], name, k) in found:
                    k += 1
                found[(head[0], row[0], name, k)] = cell
    return found


def wide_results(seeds: int = 6) -> pd.DataFrame:
    """Three long-named optimisers, every headline metric varying over the seeds."""
    rng = np.random.default_rng(3)
    rows = []
    for k, optimizer in enumerate(("modified-bso-no-chaos-replacement-tuned-loop", "de", "pso")):
        for seed in range(seeds):
            row = {
                "optimizer": optimizer,
                "trigger": True,
                "budget": "default",
                "scenario": "paper",
                "seed": seed,
            }
            for j, metric in enumerate(headline_metrics()):
                row[metric] = (1 + k + rng.uniform(0, 0.5)) * 10.0 ** (j % 5 - 2)
            rows.append(row)
    return pd.DataFrame(rows)


def test_a_word_is_what_a_browser_cannot_break():
    # a space or a hyphen between letters breaks a line; a number keeps its exponent's sign
    assert column_width(["modified-bso-tuned"]) == len("modified-") + COLUMN_PADDING
    assert column_width(["1.2e-05 (8)", "p"]) == len("1.2e-05") + COLUMN_PADDING
    assert column_width([]) == COLUMN_PADDING


def test_columns_split_into_as_few_balanced_groups_as_fit():
    widths = [9, 10, 10, 10, 11, 10, 12, 9, 9, 13]
    groups = split_columns(widths, 76)
    # in order, each column once, every group within the room, and not a full group and a stub
    assert [k for group in groups for k in group] == list(range(len(widths)))
    assert groups == [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9]]
    assert split_columns(widths, 200) == [list(range(len(widths)))]
    assert split_columns([100, 3, 4], 20) == [[0], [1, 2]]  # too wide: a table of its own
    assert split_columns([], 20) == []
    grid = Grid(["name", "n", "a", "b"], [["x-y", "3", "1 [0, 2]", "4"]], lead=2)
    assert [part.head for part in fitted(grid)] == [["name", "n", "a", "b"]]
    assert grid.lines()[1] == "|---|---:|---:|---:|"


def test_a_block_wider_than_the_page_is_split_into_tables_of_the_same_rows(monkeypatch):
    results = wide_results()
    report = analyse(results)
    text = to_markdown(report, results)
    tables = tables_in(text)
    assert all(estimated_width(table) <= TABLE_WIDTH for table in tables)
    values = [t for t in tables if t[0][:2] == ["optimizer", "runs"]]
    assert len(values) > 1  # the headline metrics do not fit one table
    # together they show every headline metric once, in its declared place, for every row
    shown = [name.rsplit(" (", 1)[0] for table in values for name in table[0][2:]]
    assert shown == [metric_column(m).name for m in headline_metrics()]
    assert all([row[:2] for row in t[1:]] == [row[:2] for row in values[0][1:]] for t in values)
    # the ranks and the tests of each part have its columns
    for table in tables:
        if table[0][1] != "runs":
            assert any(table[0][1:] == v[0][2:] for v in values)
    # the very same cells as in one table as wide as it needs
    monkeypatch.setattr(cells, "TABLE_WIDTH", 10_000)
    whole = to_markdown(report, results)
    assert len([t for t in tables_in(whole) if t[0][:2] == ["optimizer", "runs"]]) == 1
    assert cells_by_place(text) == cells_by_place(whole)


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("small")
    suite = parse_suite(SUITE, out / "small.toml")
    run_sweep(suite, out, jobs=1, progress=False, log=lambda _: None)
    return out


@pytest.mark.slow
def test_report_prints_and_writes_tables_and_figures(results, capsys, tmp_path):
    assert main(["report", str(results), "--baseline", "no-modifications"]) == 0
    printed = capsys.readouterr().out
    assert "compared: optimizer (baseline 'no-modifications')" in printed
    assert "## trigger on" in printed and "## trigger off" in printed
    assert "tracking error max after the settle time (m)" in printed and "| Friedman p |" in printed
    folder = results / "report"
    markdown = (folder / "report.md").read_text()
    assert "distance error max d31 (m)" in markdown  # the file holds every metric
    summary = pd.read_csv(folder / "summary.csv")
    assert set(summary["optimizer"]) == {
        "modified-bso[max_iterations=3]",
        "no-all-centre",
        "no-modifications",
    }
    assert set(summary["trigger"]) == {"on", "off"}
    # a run that never settled has no settling time nor errors from it; every other metric
    # has all five seeds
    settling = summary["metric"].str.contains("settl")
    assert (summary.loc[~settling, "n"] == 5).all() and (summary.loc[settling, "n"] <= 5).all()
    wilcoxon = pd.read_csv(folder / "wilcoxon.csv")
    assert set(wilcoxon["baseline"]) == {"no-modifications"}
    assert {"p", "p_holm", "a12", "n_pairs"} <= set(wilcoxon.columns)
    assert (wilcoxon["p_holm"].dropna() >= wilcoxon["p"].dropna()).all()
    ranks = pd.read_csv(folder / "ranks.csv")
    sums = ranks.groupby(["trigger", "metric"])["average_rank"].sum(min_count=1).round(9)
    # the settling time has no ranks where no seed settled for all three levels
    settling = sums.index.get_level_values("metric").str.contains("settl")
    assert sums[~settling].eq(6.0).all()
    assert (sums[settling].eq(6.0) | sums[settling].isna()).all()
    assert len(pd.read_csv(folder / "friedman.csv")) > 0
    assert len(pd.read_csv(folder / "nemenyi.csv")) > 0
    figures = folder / "figures"
    for name in (
        "distribution_tracking_error_max_m.png",
        "distribution_solves_total.png",
        "solve_time_ecdf.png",
        "trigger_counts.png",
    ):
        assert (figures / name).stat().st_size > 10_000
    drawn = {p.stem.removeprefix("distribution_") for p in figures.glob("distribution_*.png")}
    assert drawn == set(headline_metrics())
    # a results page of the folder: the commands, the date and every table marked
    page = write_results_page(results, tmp_path / "page.md", folder)
    text = page.read_text()
    assert text.startswith("# Results: suite small (")
    assert "formation-bench report" in text.splitlines()[2] and "--page" in text.splitlines()[2]
    assert "<!-- produced by: formation-bench report" in text
    # the command a reader copies from the page writes it anew: the page exists by then
    assert f"--page {tmp_path / 'page.md'} --overwrite`" in text.splitlines()[2]
    # findings written by hand into the page survive its regeneration, under the first paragraph
    findings = f"{FINDINGS_START}\nThe trigger halves the solves.\n{FINDINGS_END}"
    page.write_text(text.replace("## Headline metrics", f"{findings}\n\n## Headline metrics"))
    again = write_results_page(results, page, folder).read_text()
    assert again.count("The trigger halves the solves.") == 1
    assert again.index(FINDINGS_END) < again.index("## Headline metrics")
    assert again.replace(f"{findings}\n\n", "") == text
    assert not list(tmp_path.glob(".*.partial"))


@pytest.mark.slow
def test_the_headline_shows_each_metric_once_in_tables_that_fit_the_page(results):
    runs = load_results(results)
    report = analyse(runs, baseline="no-modifications")
    printed = to_markdown(report, runs, metrics=list(headline_metrics()))
    # the headline metrics of each block as columns, in their declared places, in tables of
    # the same rows that each fit the page; those constant over the block's runs on a line
    assert all(estimated_width(table) <= TABLE_WIDTH for table in tables_in(printed))
    first_block = printed.split("## trigger on", 1)[1].split("\n## ", 1)[0]
    values = [t for t in tables_in(first_block) if t[0][:2] == ["optimizer", "runs"]]
    shown = [name.rsplit(" (", 1)[0] for table in values for name in table[0][2:]]
    constant = next((ln for ln in first_block.splitlines() if ln.startswith("Constant")), "")
    expected = [
        metric_column(m).name
        for m in headline_metrics()
        if f"{metric_column(m).name} = " not in constant
    ]
    assert shown == expected
    assert all([row[0] for row in t[1:]] == [row[0] for row in values[0][1:]] for t in values)


def test_the_metrics_declare_how_they_are_shown():
    infos = list(metric_infos())
    places = sorted(info.headline for info in infos if info.headline is not None)
    assert places == list(range(1, len(places) + 1))
    for info in infos:
        # a label or a headline place names one column: the metric's own
        if info.label is not None or info.headline is not None:
            assert info.per is Per.RUN, info.name
        assert info.label is None or info.label.strip() == info.label != ""
    assert column_label("distance_error_max_m_d12") == "distance_error_max_m_d12 (m)"
    assert column_label("not_a_metric") == "not_a_metric"
    assert any(info.better is Better.HIGHER for info in infos)  # the smallest separation


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # seaborn on newer Matplotlib
def test_a_distribution_is_drawn_on_a_log_axis_only_when_declared_and_spread():
    from formation_bench.analysis.figures import distribution_figure

    rng = np.random.default_rng(3)
    logged = next(info.name for info in metric_infos() if info.log_scale)
    linear = next(
        info.name for info in metric_infos() if not info.log_scale and info.per is Per.RUN
    )
    frame = pd.DataFrame(
        {
            "optimizer": np.repeat(["a", "b"], 6),
            logged: 10 ** rng.uniform(0, 3, 12),
            linear: 10 ** rng.uniform(0, 3, 12),
        }
    )
    for metric, scale in ((logged, "log"), (linear, "linear")):
        fig = distribution_figure(frame, metric)
        assert fig.axes[0].get_yscale() == scale
        assert fig.axes[0].get_ylabel() == column_label(metric)
        plt.close(fig)
    narrow = frame.assign(**{logged: rng.uniform(1, 2, 12)})
    fig = distribution_figure(narrow, logged)
    assert fig.axes[0].get_yscale() == "linear"
    plt.close(fig)


def test_report_compares_with_several_baselines(results, tmp_path, capsys):
    out = tmp_path / "two"
    args = ["report", str(results), "--baseline", "no-modifications", "no-all-centre"]
    assert main([*args, "--out", str(out), "--no-figures"]) == 0
    printed = capsys.readouterr().out
    assert "(baseline 'no-modifications' and 'no-all-centre')" in printed
    assert "Against no-modifications, paired by seed" in printed
    assert "Against no-all-centre, paired by seed" in printed
    wilcoxon = pd.read_csv(out / "wilcoxon.csv")
    assert set(wilcoxon["baseline"]) == {"no-modifications", "no-all-centre"}
    # each baseline's family is Holm-adjusted on its own: two levels against each
    per_family = wilcoxon.groupby(["trigger", "metric", "baseline"]).size()
    assert (per_family == 2).all()
    pair = wilcoxon.set_index(["trigger", "metric", "baseline", "optimizer"])
    key = ("on", "tracking_error_max_m")
    ab = pair.loc[(*key, "no-all-centre", "no-modifications")]
    ba = pair.loc[(*key, "no-modifications", "no-all-centre")]
    assert ab["p"] == pytest.approx(ba["p"]) and ab["a12"] == pytest.approx(1 - ba["a12"])


def test_report_compares_triggers_and_refuses_an_unknown_baseline(results, tmp_path, capsys):
    out = tmp_path / "rep"
    code = main(["report", str(results), "--compare", "trigger", "--out", str(out), "--no-figures"])
    assert code == 0
    assert "compared: trigger (baseline 'off')" in capsys.readouterr().out
    assert not (out / "figures").exists()
    # two levels: the tests across all levels do not apply, and each file says so
    for name in ("friedman", "ranks", "nemenyi"):
        note = pd.read_csv(out / f"{name}.csv")
        assert list(note.columns) == ["note"] and len(note) == 1
        assert "3 or more levels" in note["note"][0]
    assert len(pd.read_csv(out / "wilcoxon.csv")) > 0
    assert main(["report", str(results), "--baseline", "pso", "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith("formation-bench report: error: --baseline: 'pso'")
    assert "no-modifications" in err


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # seaborn on newer Matplotlib
def test_the_trigger_figure_draws_the_solves_per_run_beside_the_conditions():
    from formation_bench.analysis.figures import trigger_conditions_figure

    frame = pd.DataFrame(
        {
            "optimizer": np.repeat(["a", "b"], 4),
            "trigger": ["on"] * 6 + ["off"] * 2,
            "solves_total": [10, 12, 11, 13, 20, 22, 99, 99],
            "trigger_distance": [3, 4, 3, 4, 8, 9, 0, 0],
            "trigger_expiry": [3] * 8,
        }
    )
    fig = trigger_conditions_figure(frame)
    solves, conditions = fig.axes[:2]
    assert solves.get_ylabel() == column_label("solves_total")
    drawn = np.concatenate([c.get_offsets()[:, 1] for c in solves.collections])
    assert sorted(drawn) == [10, 11, 12, 13, 20, 22]  # every run with the trigger on
    assert [round(b.get_height(), 6) for b in solves.patches] == [11.5, 21.0]  # the medians
    assert conditions.get_ylabel() == "solves per run at which the condition held"
    plt.close(fig)
