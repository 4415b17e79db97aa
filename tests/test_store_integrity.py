"""The results store proves it is intact: seals, page checksums, key checks, the manifest.

Unit tests of each detection, then a seeded fault-injection test that garbles random bytes
of run, trace, score and manifest files and checks that resume redoes the file, the readers
name it instead of using it, and nothing is lost, silently changed or met with a traceback.
"""

import json
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from formation_bench.cli.main import main
from formation_bench.experiments import score, seal
from formation_bench.experiments.errors import IntegrityError, ManifestError
from formation_bench.experiments.manifest import read_manifest, write_manifest
from formation_bench.experiments.seal import decode, read_sealed, unseal
from formation_bench.experiments.store import ResultStore, load_results, load_traces
from formation_bench.experiments.suite import load_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.instances.library import Library, shipped
from formation_bench.optimizers import Budget
from formation_bench.pipeline.record import is_timing_column

SUITE = """\
name = "{name}"
seeds = [0, 1]
triggers = [true, false]
trace = true

[[optimizers]]
name = "modified-bso"
overrides = {{ max_iterations = 3 }}

[[scenarios]]
name = "paper"
overrides = {{ n_steps = 10, settle_time_s = 1.0 }}
"""
RUNS = 4
TRACE_TIMING = ("solve_time_s",)
"""Trace columns that measure the machine, not the run."""
SCORE_TIMING = ("seconds",)
"""Score columns that measure the machine, not the run, besides the provenance's timing ones
(:func:`~formation_bench.pipeline.record.is_timing_column`)."""


def suite_file(folder: Path, name: str = "integrity") -> Path:
    path = folder / f"{name}.toml"
    path.write_text(SUITE.format(name=name))
    return path


def sweep(suite_path: Path, out: Path, messages: list[str] | None = None):
    log = messages.append if messages is not None else (lambda _: None)
    return run_sweep(load_suite(str(suite_path)), out, jobs=1, progress=False, log=log)


def results_of(out: Path) -> pd.DataFrame:
    frame = load_results(out, strict=True)
    keep = [c for c in frame.columns if not is_timing_column(c)]
    return frame[keep].sort_values("run_key").reset_index(drop=True)


def traces_of(out: Path) -> pd.DataFrame:
    frame = load_traces(out, strict=True).drop(columns=list(TRACE_TIMING))
    return frame.sort_values(["run_key", "step", "uav"]).reset_index(drop=True)


def tiny_library() -> Library:
    library = shipped()
    pick = np.linspace(0, len(library) - 1, 3).astype(int)
    return Library(
        library.version, library.manifest, {k: v[pick] for k, v in library.arrays.items()}
    )


def score_runs_of(library: Library) -> list[score.ScoreRun]:
    return score.score_runs("random-search", {}, [Budget(40)], [0, 1], library=library)


def scores_of(out: Path) -> pd.DataFrame:
    scores = score.load_scores(out)
    return scores.drop(columns=[c for c in scores if c in SCORE_TIMING or is_timing_column(c)])


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """A finished sweep (runs, traces, manifest) and score runs, with their contents."""
    root = tmp_path_factory.mktemp("integrity")
    path = suite_file(root)
    out = root / "store"
    summary = sweep(path, out)
    assert summary.stored == RUNS and not summary.failed
    library = tiny_library()
    assert len(list(score.run_scores(score_runs_of(library), out, jobs=1, library=library))) == 2
    return path, out, results_of(out), traces_of(out), scores_of(out), library


def copy_of(stored, tmp_path: Path) -> Path:
    out = tmp_path / "store"
    shutil.copytree(stored[1], out)
    return out


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


# --- seals and page checksums ------------------------------------------------------------------


def test_every_store_file_carries_a_seal_naming_its_kind_and_key(stored):
    _, out, *_ = stored
    store = ResultStore(out)
    for key in store.keys():
        _, run_seal = read_sealed(store.run_path(key), "run", key)
        _, trace_seal = read_sealed(store.trace_path(key), "trace", key)
        assert run_seal["trace"] == trace_seal["sha256"]
    for path in (out / "score").glob("*.parquet"):
        _, seal = read_sealed(path, "score", path.stem)
        assert seal["kind"] == "score" and seal["key"] == path.stem
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest["manifest_sha256"]) == 64
    assert read_manifest(store)["suite"]["name"] == "integrity"


def test_every_footer_byte_is_covered_by_the_seal(stored):
    """Page checksums cover data pages only; the seal's digest covers the footer too."""
    _, out, *_ = stored
    path = next((out / "runs").glob("*.parquet"))
    data = path.read_bytes()
    footer = int.from_bytes(data[-8:-4], "little") + 8
    for at in range(len(data) - footer, len(data)):
        garbled = bytearray(data)
        garbled[at] ^= 0x01
        with pytest.raises(IntegrityError):
            unseal(bytes(garbled))


@pytest.mark.parametrize("folder", ["traces", "runs"])
def test_data_pages_are_written_with_checksums_that_reading_verifies(stored, folder):
    _, out, *_ = stored
    path = next((out / folder).glob("*.parquet"))
    data = path.read_bytes()
    chunk = pq.ParquetFile(path).metadata.row_group(0).column(0)
    end = (chunk.dictionary_page_offset or chunk.data_page_offset) + chunk.total_compressed_size
    garbled = bytearray(data)
    garbled[end - 1] ^= 0xFF  # the last byte of the column's last data page
    with pytest.raises(IntegrityError, match=r"(?i)crc|checksum"):
        decode(bytes(garbled))


# --- runs and traces ---------------------------------------------------------------------------


def test_a_garbled_run_file_is_named_left_out_and_redone(stored, tmp_path, capsys):
    path, _, results, *_ = stored
    out = copy_of(stored, tmp_path)
    victim = sorted((out / "runs").glob("*.parquet"))[1]
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0x10
    victim.write_bytes(bytes(data))
    frame = load_results(out)
    assert victim.stem not in set(frame["run_key"]) and len(frame) == RUNS - 1
    warning = one_line(capsys.readouterr().err)
    assert f"left out {victim}" in warning and "SHA-256 mismatch" in warning
    summary = sweep(path, out)
    assert summary.redo == {"corrupt": 1} and summary.stored == 1
    pd.testing.assert_frame_equal(results_of(out), results, check_exact=True)


def test_a_run_file_under_another_runs_name_is_detected_everywhere(stored, tmp_path, capsys):
    path, _, results, *_ = stored
    out = copy_of(stored, tmp_path)
    files = sorted((out / "runs").glob("*.parquet"))
    shutil.copy(files[0], files[1])
    store = ResultStore(out)
    status = store.status(files[1].stem, "unused", need_trace=False)
    assert status.state == "corrupt" and "another run's name" in status.detail
    frame = load_results(out)
    assert frame["run_key"].is_unique and len(frame) == RUNS - 1
    assert f"left out {files[1]}" in one_line(capsys.readouterr().err)
    code = main(["report", str(out), "--out", str(tmp_path / "rep"), "--no-figures"])
    assert code == 0
    err = capsys.readouterr().err
    assert f"left out {files[1]}" in err and "Traceback" not in err
    summary = pd.read_csv(tmp_path / "rep" / "summary.csv")
    counted = summary.loc[summary["metric"] == "tracking_error_max_m", "n"].sum()
    assert counted == RUNS - 1  # one run fewer, not one more
    assert sweep(path, out).redo == {"corrupt": 1}
    pd.testing.assert_frame_equal(results_of(out), results, check_exact=True)


def test_an_unsealed_copy_under_another_name_is_caught_by_its_run_key(stored, tmp_path, capsys):
    out = copy_of(stored, tmp_path)
    files = sorted((out / "runs").glob("*.parquet"))
    pq.write_table(pq.read_table(files[0]), files[1])  # as written before seals were kept
    frame = load_results(out)
    assert frame["run_key"].is_unique and len(frame) == RUNS - 1
    assert f"holds run {files[0].stem}" in capsys.readouterr().err


def test_a_swapped_or_earlier_trace_is_redone(stored, tmp_path, capsys):
    path, _, results, traces, *_ = stored
    out = copy_of(stored, tmp_path)
    store = ResultStore(out)
    keys = store.keys()
    shutil.copy(store.trace_path(keys[0]), store.trace_path(keys[1]))  # another run's trace
    # an earlier trace of the same run: sealed for its key, but not the one its row names
    row = pq.read_table(store.run_path(keys[2])).to_pylist()[0]
    trace = load_traces(out, [keys[2]]).drop(columns="run_key")
    store.write_run(keys[2], row, trace.assign(x_m=trace["x_m"] + 1.0))
    earlier = store.trace_path(keys[2]).read_bytes()
    store.write_run(keys[2], row, trace)
    store.trace_path(keys[2]).write_bytes(earlier)
    frame = load_traces(out)
    assert set(frame["run_key"]) == {keys[0], keys[3]}
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "another run's name" in err[0]
    assert "not the trace stored with its run" in err[1]
    summary = sweep(path, out)
    assert summary.redo == {"corrupt": 2} and summary.stored == 2
    pd.testing.assert_frame_equal(traces_of(out), traces, check_exact=True)
    pd.testing.assert_frame_equal(results_of(out), results, check_exact=True)


def test_files_from_before_seals_are_used_with_a_notice_and_redone(stored, tmp_path, capsys):
    path, _, results, *_ = stored
    out = copy_of(stored, tmp_path)
    for file in (out / "runs").glob("*.parquet"):
        pq.write_table(pq.read_table(file), file)
    assert len(load_results(out)) == RUNS
    notice = one_line(capsys.readouterr().err)
    assert f"{RUNS} file(s) in {out / 'runs'}" in notice and "unverified" in notice
    summary = sweep(path, out)
    assert summary.redo == {"unverified": RUNS} and summary.stored == RUNS
    assert len(load_results(out)) == RUNS and capsys.readouterr().err == ""
    pd.testing.assert_frame_equal(results_of(out), results, check_exact=True)


def test_run_files_sealed_by_the_earlier_writer_are_kept_and_read_the_same(
    stored, tmp_path, monkeypatch
):
    """Run files were once written as traces still are (zstd, dictionaries, statistics)."""
    path, _, results, *_ = stored
    out = copy_of(stored, tmp_path)
    store = ResultStore(out)
    monkeypatch.setattr(seal, "_WRITER_OPTIONS", {})
    for key in store.keys():
        row = pq.read_table(store.run_path(key)).to_pylist()[0]
        store.write_run(key, row, load_traces(out, [key]).drop(columns="run_key"))
    monkeypatch.undo()
    chunk = pq.ParquetFile(store.run_path(key)).metadata.row_group(0).column(0)
    assert chunk.compression == "ZSTD" and chunk.statistics is not None
    summary = sweep(path, out)
    assert summary.already == RUNS and summary.stored == 0 and not summary.redo
    pd.testing.assert_frame_equal(results_of(out), results, check_exact=True)


# --- score runs --------------------------------------------------------------------------------


def test_a_damaged_or_misplaced_score_file_is_named_left_out_and_redone(stored, tmp_path, capsys):
    *_, scores, library = stored
    out = copy_of(stored, tmp_path)
    files = sorted((out / "score").glob("*.parquet"))
    shutil.copy(files[0], files[1])
    assert score.stored_keys(out) == {files[0].stem}
    assert set(score.load_scores(out)["run_key"]) == {files[0].stem}
    assert f"left out {files[1]}" in one_line(capsys.readouterr().err)
    for argv in (["export-ioh", str(out)], ["report", str(out), "--no-figures"]):
        assert main([*argv, "--out", str(tmp_path / argv[0])]) == 0
        err = capsys.readouterr().err
        assert f"left out {files[1]}" in err and "Traceback" not in err
    redone = [r.key for r in score.run_scores(score_runs_of(library), out, library=library)]
    assert redone == [files[1].stem]
    pd.testing.assert_frame_equal(scores_of(out), scores, check_exact=True)


# --- the manifest ------------------------------------------------------------------------------


def _wrong_types(text: str) -> bytes:
    manifest = json.loads(text)
    del manifest["manifest_seal"], manifest["manifest_sha256"]  # as written before checksums
    manifest["sessions"] = {"state": "done"}
    return json.dumps(manifest).encode()


def _changed_value(text: str) -> bytes:
    return text.replace('"state": "done"', '"state": "dune"', 1).encode()


DAMAGE = {
    "not UTF-8": lambda text: b"\xff\xfe" + text.encode()[2:],
    "truncated": lambda text: text.encode()[: len(text) // 2],
    "empty": lambda text: b"",
    "a JSON list": lambda text: b"[]",
    "wrong types": _wrong_types,
    "a changed value": _changed_value,
    "a renamed checksum field": lambda text: text.replace("_sha256", "_sha257").encode(),
    "missing": None,
}
EXPECTED = {
    "not UTF-8": "is not UTF-8",
    "truncated": "is not valid JSON",
    "empty": "is empty",
    "a JSON list": "holds a JSON list, not an object",
    "wrong types": "'sessions' of JSON type dict",
    "a changed value": "fails its SHA-256 checksum",
    "a renamed checksum field": "fails its SHA-256 checksum",
    "missing": f"is missing while {{runs}} holds {RUNS} stored runs",
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_manifest_stops_the_sweep_with_the_command_that_rebuilds_it(
    stored, tmp_path, capsys, damage
):
    path, _, results, *_ = stored
    out = copy_of(stored, tmp_path)
    manifest = out / "manifest.json"
    if DAMAGE[damage] is None:
        manifest.unlink()
    else:
        manifest.write_bytes(DAMAGE[damage](manifest.read_text()))
    before = {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    for extra in ([], ["--dry-run"]):
        assert main(["sweep", str(path), "--out", str(out), *extra]) == 2
        line = one_line(capsys.readouterr().err)
        assert str(manifest) in line and "--rebuild-manifest" in line
        assert EXPECTED[damage].format(runs=out / "runs") in line
    assert {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} == before
    command = line.split("; ")[-1].split("'")[1]
    assert main(shlex.split(command)[1:]) == 0
    assert "rebuilt" in capsys.readouterr().out
    assert main(["sweep", str(path), "--out", str(out), "--no-progress"]) == 0
    assert f"{RUNS} already stored" in capsys.readouterr().err
    sessions = read_manifest(ResultStore(out))["sessions"]
    assert [s["state"] for s in sessions] == ["rebuilt", "done"]
    assert sessions[0]["rebuilt_from"] == {"runs": RUNS, "not_in_suite_file": 0, "damaged": 0}
    pd.testing.assert_frame_equal(results_of(out), results, check_exact=True)


def test_rebuilding_refuses_an_intact_manifest_and_runs_of_another_suite(stored, tmp_path, capsys):
    path, *_ = stored
    out = copy_of(stored, tmp_path)
    before = (out / "manifest.json").read_bytes()
    assert main(["sweep", str(path), "--out", str(out), "--rebuild-manifest"]) == 2
    assert "is intact; nothing to rebuild" in one_line(capsys.readouterr().err)
    assert (out / "manifest.json").read_bytes() == before
    (out / "manifest.json").unlink()
    other = suite_file(tmp_path, "other")
    assert main(["sweep", str(other), "--out", str(out), "--rebuild-manifest"]) == 2
    line = one_line(capsys.readouterr().err)
    assert f"holds runs of suite 'integrity' ({RUNS} runs), not of suite 'other'" in line
    assert not (out / "manifest.json").exists()


def test_a_manifest_with_a_newer_field_is_accepted_and_a_fresh_folder_has_none(tmp_path):
    store = ResultStore(tmp_path / "new")
    assert read_manifest(store) is None
    store.create()
    assert read_manifest(store) is None  # runs/ empty: nothing to protect yet
    manifest = {"format": 1, "created": "t", "updated": "t", "suite": {"name": "s"}}
    write_manifest(store, {**manifest, "sessions": [], "extra": {"from": "a later version"}})
    with pytest.raises(ManifestError, match=r"suite\.sha256"):
        read_manifest(store)
    manifest["suite"]["sha256"] = "0" * 64
    write_manifest(store, {**manifest, "sessions": [], "extra": {"from": "a later version"}})
    assert read_manifest(store)["extra"] == {"from": "a later version"}


# --- fault injection ---------------------------------------------------------------------------


def garble(data: bytes, rng: np.random.Generator) -> bytes:
    """``data`` truncated (one time in five) or with 1-16 bytes from a random offset replaced
    by random values; never ``data`` itself."""
    if rng.random() < 0.2:
        return data[: int(rng.integers(0, len(data)))]
    while True:
        at = int(rng.integers(0, len(data)))
        length = min(int(rng.integers(1, 17)), len(data) - at)
        values = rng.integers(0, 256, size=length, dtype=np.uint8).tobytes()
        if values != data[at : at + length]:
            return data[:at] + values + data[at + length :]


@dataclass
class Tally:
    trials: int = 0
    survived: int = 0
    lost: int = 0
    changed: int = 0
    tracebacks: int = 0

    def line(self, kind: str) -> str:
        return (
            f"{kind}: {self.trials} trials, {self.survived} survived, {self.lost} lost, "
            f"{self.changed} silently changed, {self.tracebacks} tracebacks"
        )


TRIALS = {"run": 25, "trace": 25, "score": 25, "manifest": 25}


def _trial_on_sweep(stored, kind, rng, tmp_path, capsys) -> tuple[bool, int, bool]:
    """One garble of a run or trace file: (survived, runs lost, silently changed)."""
    path, _, results, traces, *_ = stored
    out = copy_of(stored, tmp_path)
    folder = out / ("runs" if kind == "run" else "traces")
    victim = sorted(folder.glob("*.parquet"))[int(rng.integers(0, RUNS))]
    victim.write_bytes(garble(victim.read_bytes(), rng))
    capsys.readouterr()
    reported = True
    if kind == "run":
        read = load_results(out)
        reported = main(["report", str(out), "--out", str(tmp_path / "rep"), "--no-figures"]) == 0
    else:
        read = load_traces(out)
    err = capsys.readouterr().err
    named = reported and err.count(f"left out {victim}") == (2 if kind == "run" else 1)
    used = victim.stem in set(read["run_key"])
    summary = sweep(path, out)
    redone = summary.redo == {"corrupt": 1} and summary.stored == 1
    final = results_of(out)
    lost = RUNS - len(final)
    same = final.equals(results) and traces_of(out).equals(traces)
    return named and not used and redone and same and lost == 0, lost, used or not same


def _trial_on_score(stored, rng, tmp_path, capsys) -> tuple[bool, int, bool]:
    *_, scores, library = stored
    out = copy_of(stored, tmp_path)
    victim = sorted((out / "score").glob("*.parquet"))[int(rng.integers(0, 2))]
    victim.write_bytes(garble(victim.read_bytes(), rng))
    capsys.readouterr()
    exported = main(["export-ioh", str(out), "--out", str(tmp_path / "ioh")]) == 0
    read = score.load_scores(out)
    named = exported and capsys.readouterr().err.count(f"left out {victim}") == 2
    used = victim.stem in set(read["run_key"])
    redone = [r.key for r in score.run_scores(score_runs_of(library), out, library=library)]
    final = scores_of(out)
    lost = 2 - final["run_key"].nunique()
    same = final.equals(scores)
    return named and not used and redone == [victim.stem] and same, lost, used or not same


def _trial_on_manifest(stored, rng, tmp_path, capsys) -> tuple[bool, int, bool]:
    path, _, results, *_ = stored
    out = copy_of(stored, tmp_path)
    manifest = out / "manifest.json"
    manifest.write_bytes(garble(manifest.read_bytes(), rng))
    capsys.readouterr()
    stopped = main(["sweep", str(path), "--out", str(out)]) == 2
    line = capsys.readouterr().err.strip()
    named = len(line.splitlines()) == 1 and str(manifest) in line
    rebuilt = False
    if stopped and named:
        command = line.split("; ")[-1].split("'")[1]
        rebuilt = main(shlex.split(command)[1:]) == 0
    resumed = main(["sweep", str(path), "--out", str(out), "--no-progress"]) == 0
    final = results_of(out)
    lost = RUNS - len(final)
    same = final.equals(results)
    return stopped and named and rebuilt and resumed and same, lost, not stopped or not same


@pytest.mark.slow
def test_random_garbles_are_redone_named_and_never_used(stored, tmp_path, capsys):
    rng = np.random.default_rng(np.random.SeedSequence(20_251_125))
    tallies = {kind: Tally() for kind in TRIALS}
    for kind, trials in TRIALS.items():
        tally = tallies[kind]
        for trial in range(trials):
            where = tmp_path / f"{kind}-{trial}"
            where.mkdir()
            tally.trials += 1
            try:
                if kind == "score":
                    survived, lost, changed = _trial_on_score(stored, rng, where, capsys)
                elif kind == "manifest":
                    survived, lost, changed = _trial_on_manifest(stored, rng, where, capsys)
                else:
                    survived, lost, changed = _trial_on_sweep(stored, kind, rng, where, capsys)
            except Exception:  # raised by the commands or the store: a user sees a traceback
                tally.tracebacks += 1
                continue
            tally.survived += survived
            tally.lost += lost
            tally.changed += changed
            shutil.rmtree(where)
    with capsys.disabled():
        print()
        for kind, tally in tallies.items():
            print(tally.line(kind))
    assert sum(t.trials for t in tallies.values()) >= 50
    for tally in tallies.values():
        assert (tally.survived, tally.lost, tally.changed, tally.tracebacks) == (
            tally.trials,
            0,
            0,
            0,
        )
