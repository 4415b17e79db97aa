"""The report of a folder of tuned-variant files (``formation-bench report DIR`` on what
``tune`` writes): the table, the best-so-far curves, the flattening point, the page and its
figure, and bad files refused before anything is written."""

import json
from pathlib import Path

import pandas as pd
import pytest
from test_scoring import joined_rows, table_widths

from formation_bench.analysis.cells import TABLE_WIDTH
from formation_bench.analysis.tuning_report import (
    FLAT_TRIALS,
    flattening_sentence,
    flattening_trials,
    read_folder,
    read_tuned,
    to_markdown,
    variants_table,
)
from formation_bench.cli.main import main
from perf.page_numbers import markdown_tables


def tuned_file(
    folder: Path,
    base: str,
    history: list[float],
    *,
    kind: str = "solve",
    wall_time_s: float = 30.0,
    values: dict | None = None,
) -> Path:
    """A tuned-variant file as ``formation-bench tune`` writes it (interface format 1)."""
    name = f"{base}-tuned" if kind == "solve" else f"{base}-tuned-loop"
    solve = kind == "solve"
    data = {
        "format": 1,
        "name": name,
        "base": base,
        "values": values if values is not None else {"inertia": 0.52, "boundary": "clip"},
        "objective": {
            "kind": kind,
            "budget": 1200,
            "metric": "median normalised gap" if solve else "steady_state_cost",
            "statistic": "median",
            "split": "validation" if solve else None,
            "library": "v2" if solve else None,
            "suite": None if solve else "comparison",
            "seeds": None if solve else [1000, 1001, 1002],
            "problems": 60 if solve else None,
        },
        "tuner": {
            "library": "optuna",
            "version": "4.5.0",
            "sampler": "TPESampler",
            "trials": len(history),
            "batch": 2,
            "seed": 7,
        },
        "provenance": {
            "date": "2026-11-28T03:00:00+00:00",
            "commit": "0123456789abcdef",
            "version": "0.3.0",
            "command": f"formation-bench tune --optimizer {base} --trials {len(history)}",
            "wall_time_s": wall_time_s,
            "machine": "AMD EPYC, 2 cores",
        },
        "default_value": history[0],
        "best_value": min(history),
        "history": history,
    }
    path = folder / f"{name}.json"
    path.write_text(json.dumps(data, indent=1))
    return path


def tuning_folder(root: Path) -> Path:
    folder = root / "tuning"
    folder.mkdir()
    # best so far 1, .8, .5, .499, .499, .4985: after 3 trials the rest gains .0015 < 1 % of 1
    tuned_file(folder, "pso", [1.0, 0.8, 0.5, 0.499, 0.6, 0.4985], wall_time_s=40.0)
    # 200 -> 150 at the last trial: still improving, flattening point = its 4 trials
    tuned_file(folder, "de", [200.0, 210.0, 199.5, 150.0], kind="loop", wall_time_s=3600.0,
               values={"crossover": 0.9, "immediate": True})  # fmt: skip
    return folder


def test_the_flattening_point_and_the_table_by_hand(tmp_path):
    variants = read_folder(tuning_folder(tmp_path))
    assert [v.name for v in variants] == ["de-tuned-loop", "pso-tuned"]
    de, pso = variants
    assert flattening_trials(pso) == 3
    assert flattening_trials(de) == 4
    assert list(pso.best_so_far) == [1.0, 0.8, 0.5, 0.499, 0.499, 0.4985]
    table = variants_table(variants).set_index("variant")
    assert table.loc["pso-tuned", "settings"] == "inertia=0.52, boundary=clip"
    assert table.loc["de-tuned-loop", "settings"] == "crossover=0.9, immediate=true"
    assert table.loc["de-tuned-loop", "objective"] == "loop"
    assert table.loc["pso-tuned", "tuned_value"] == 0.4985
    markdown = to_markdown(variants)
    assert "Total tuning wall time: 60.7 min (3640 s) over 2 variants." in markdown
    assert "de-tuned-loop 4 of 4; pso-tuned 3 of 6." in markdown
    assert "The largest: 4 trials (de-tuned-loop)." in markdown
    assert "Still improving by 1 % or more at its last trial: de-tuned-loop." in markdown
    # six trials, three of them flat: short of the 25 the rule asks for
    assert (
        "Not flattened (no such gain in the last 25 trials or more): de-tuned-loop, pso-tuned."
        in markdown
    )
    assert "suite comparison, seeds 1000, 1001, 1002" in markdown


def test_the_table_of_the_variants_fits_the_page_in_tables_of_the_same_rows(tmp_path):
    markdown = to_markdown(read_folder(tuning_folder(tmp_path)))
    tables = [t for t in markdown_tables(markdown) if t.header[0] == "variant"]
    assert len(tables) == 2 and max(table_widths(markdown)) <= TABLE_WIDTH
    # every row in every part, named by its variant, every cell once over the parts
    assert [[row[0] for row in t.rows] for t in tables] == [["de-tuned-loop", "pso-tuned"]] * 2
    rows = joined_rows(markdown, ["variant"])
    assert rows[("pso-tuned",)] == [
        "pso", "solve", "median normalised gap", "1200", "6", "2", "7", "1", "0.4985",
        "inertia=0.52, boundary=clip", "40.0 s",
    ]  # fmt: skip
    assert rows[("de-tuned-loop",)][:5] == ["de", "loop", "median steady_state_cost", "1200", "4"]
    # what each tuning was, then what it found
    assert tables[0].header[1:5] == ["base", "objective", "metric", "budget"]
    assert "tuned settings" in tables[1].header


def test_a_curve_has_flattened_after_that_many_trials_without_a_gain(tmp_path):
    folder = tmp_path / "tuning"
    folder.mkdir()
    # the last gain of 1 % or more at trial 3, then FLAT_TRIALS trials that gain less
    tuned_file(folder, "pso", [1.0, 0.8, 0.5] + [0.4999] * FLAT_TRIALS)
    # one trial fewer: one short of the rule
    tuned_file(folder, "de", [1.0, 0.8, 0.5] + [0.4999] * (FLAT_TRIALS - 1))
    variants = {v.name: v for v in read_folder(folder)}
    assert flattening_trials(variants["pso-tuned"]) == 3
    assert flattening_sentence([variants["pso-tuned"]]).endswith(
        f"Every curve has flattened (no such gain in the last {FLAT_TRIALS} trials or more)."
    )
    assert flattening_sentence(list(variants.values())).endswith(
        f"Not flattened (no such gain in the last {FLAT_TRIALS} trials or more): de-tuned."
    )


def test_the_tuning_page_and_its_figure_beside_it(tmp_path, capsys):
    folder = tuning_folder(tmp_path)
    page = tmp_path / "docs" / "results" / "tuning.md"
    page.parent.mkdir(parents=True)
    assert main(["report", str(folder), "--page", str(page)]) == 0
    report = folder / "report"
    curves = pd.read_csv(report / "tuning_curves.csv")
    pso = curves[curves["variant"] == "pso-tuned"]
    assert pso["best_so_far_relative"].tolist() == pytest.approx(
        [1, 0.8, 0.5, 0.499, 0.499, 0.4985]
    )
    de = curves[curves["variant"] == "de-tuned-loop"]
    assert de["best_so_far_relative"].tolist() == pytest.approx([1, 1, 0.9975, 0.75])
    assert (report / "figures" / "tuning_best_so_far.png").stat().st_size > 10_000
    image = tmp_path / "docs" / "images" / "tuning_best_so_far.png"
    assert image.read_bytes() == (report / "figures" / "tuning_best_so_far.png").read_bytes()
    text = page.read_text()
    assert text.startswith("# Results: tuning (2026-11-28)")
    assert "Tuned variants, made by the commands listed at the end of this page" in text
    assert "\n## How this page was made\n\n```text\nformation-bench tune " in text
    assert "formation-bench tune --optimizer pso --trials 6" in text
    assert "![best value found so far / default value, against the trials]" in text
    assert "(../images/tuning_best_so_far.png)" in text
    table_at = text.index("| variant | base |")
    assert "<!-- produced by: formation-bench report" in text[:table_at].splitlines()[-2]
    assert "machine: AMD EPYC, 2 cores; date: 2026-11-28" in text[:table_at]
    # written again only with --overwrite, the figure too
    capsys.readouterr()
    assert main(["report", str(folder), "--out", str(tmp_path / "r2"), "--page", str(page)]) == 2
    assert "add --overwrite" in capsys.readouterr().err
    page.unlink()
    assert main(["report", str(folder), "--out", str(tmp_path / "r3"), "--page", str(page)]) == 2
    err = capsys.readouterr().err
    assert f"its figure {image}: exists; add --overwrite" in err and not page.exists()


def _broken(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


BAD_FILES = [
    (lambda d: d.update(format=2), "format: must be 1"),
    (lambda d: d.pop("history"), "history: must be a list of 6 finite numbers"),
    (lambda d: d.update(history=[1.0, 2.0]), "history: must be a list of 6 finite numbers"),
    (lambda d: d["tuner"].update(trials=0), "tuner.trials: must be an integer >= 1"),
    (lambda d: d["objective"].update(kind="grid"), "objective.kind: must be one of solve, loop"),
    (lambda d: d.update(name="pso-tuned-loop"), "name: must be the base's name with '-tuned'"),
    (lambda d: d["provenance"].update(date="yesterday"), "provenance.date: must be an ISO date"),
    (lambda d: d["values"].update(inertia=[1]), "values: must be an object of setting names"),
    (lambda d: d.update(default_value="1"), "default_value: must be a finite number"),
]


@pytest.mark.parametrize(("change", "needle"), BAD_FILES)
def test_a_bad_tuned_file_is_named_with_its_field_and_nothing_is_written(
    tmp_path, capsys, change, needle
):
    folder = tuning_folder(tmp_path)
    _broken(folder / "pso-tuned.json", change)
    page = tmp_path / "page.md"
    assert main(["report", str(folder), "--page", str(page), "--no-figures"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"formation-bench report: error: {folder / 'pso-tuned.json'}: ")
    assert needle in err and "\n" not in err
    assert not (folder / "report").exists() and not page.exists()


def test_a_file_that_is_not_json_or_not_an_object_is_named(tmp_path, capsys):
    folder = tuning_folder(tmp_path)
    (folder / "pso-tuned.json").write_text('{"format": 1,')
    assert main(["report", str(folder), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert f"{folder / 'pso-tuned.json'}: not a JSON file" in err
    (folder / "pso-tuned.json").write_text('{"format": NaN}')
    assert main(["report", str(folder), "--no-figures"]) == 2
    assert "NaN is not a JSON number" in capsys.readouterr().err
    (folder / "pso-tuned.json").write_text("[1]")
    with pytest.raises(ValueError, match="the file: must be a JSON object"):
        read_tuned(folder / "pso-tuned.json")
    assert not (folder / "report").exists()


def test_options_that_compare_runs_are_refused_for_a_tuning_folder(tmp_path, capsys):
    folder = tuning_folder(tmp_path)
    assert main(["report", str(folder), "--baseline", "pso-tuned", "--no-figures"]) == 2
    assert "--baseline: " in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.json").write_text("{}")  # not a tuned-variant file by its name
    assert main(["report", str(empty)]) == 2
    assert "no tuned-variant files NAME-tuned.json" in capsys.readouterr().err
    assert not (folder / "report").exists() and not (empty / "report").exists()
