"""A results page takes a suite folder's provenance from its manifest read verified: a manifest
whose seal is broken (a field edited without resealing, the file garbled, the seal taken away)
stops ``formation-bench report DIR --page FILE`` in one line naming the manifest and what is
wrong, exit 2, with no page written and an existing page left as it was; an intact manifest
still gives the page its commands, version and machine.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from formation_bench.analysis.results_page import (
    WRITTEN_BY,
    is_results_page,
    suite_provenance,
    write_results_page,
)
from formation_bench.cli.main import main
from formation_bench.experiments.errors import ManifestError
from formation_bench.experiments.seal import MANIFEST_DIGEST, MANIFEST_SEAL
from formation_bench.experiments.store import load_results
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import run_sweep

SUITE = """\
name = "page-provenance"
seeds = 2
triggers = [true, false]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 3 }

[[scenarios]]
name = "paper"
overrides = { n_steps = 10, settle_time_s = 1.0 }
"""
INVENTED_VERSION = "99.0.0"
"""The formation-bench version an edit writes into a manifest (no run was made by it)."""


@pytest.fixture(scope="module")
def stored(tmp_path_factory) -> Path:
    """A finished sweep of four runs (runs, traces, sealed manifest), never modified: every
    test damages its own copy."""
    root = tmp_path_factory.mktemp("page-provenance")
    out = root / "store"
    suite = parse_suite(SUITE, root / "page-provenance.toml")
    assert run_sweep(suite, out, jobs=1, progress=False, log=lambda _: None).stored == 4
    return out


def copy_of(stored: Path, tmp_path: Path) -> Path:
    out = tmp_path / "store"
    shutil.copytree(stored, out)
    return out


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def snapshot(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() if p.is_file() else b"<dir>"
        for p in sorted(root.rglob("*"))
    }


def edit_a_field(manifest: Path) -> None:
    """Change the recorded formation-bench version in place, keeping the seal and every other
    byte: what a hand edit that does not reseal leaves."""
    text = manifest.read_text()
    version = json.loads(text)["versions"]["formation-bench"]
    edited = text.replace(
        f'"formation-bench": "{version}"', f'"formation-bench": "{INVENTED_VERSION}"'
    )
    assert edited != text
    kept = json.loads(edited)
    assert MANIFEST_SEAL in kept and MANIFEST_DIGEST in kept  # sealed still, and wrongly
    manifest.write_text(edited)


def garble(manifest: Path) -> None:
    """Cut the file in the middle, as an interrupted copy leaves it."""
    data = manifest.read_bytes()
    manifest.write_bytes(data[: len(data) // 2])


def strip_seal(manifest: Path) -> None:
    """Take the seal away and edit a field: a manifest that could then pass for unsealed."""
    fields = json.loads(manifest.read_text())
    del fields[MANIFEST_SEAL], fields[MANIFEST_DIGEST]
    fields["versions"]["formation-bench"] = INVENTED_VERSION
    manifest.write_text(json.dumps(fields, indent=2))


DAMAGES = {
    "field edited without resealing": (
        edit_a_field,
        "fails its SHA-256 checksum: it changed after it was written",
    ),
    "garbled": (garble, "is not valid JSON"),
    "seal taken away": (strip_seal, "has no seal"),
}


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_suite_provenance_refuses_a_manifest_with_a_broken_seal(stored, tmp_path, damage):
    out = copy_of(stored, tmp_path)
    results = load_results(out)
    damaged, reason = DAMAGES[damage]
    damaged(out / "manifest.json")
    with pytest.raises(ManifestError, match=reason) as refused:
        suite_provenance(out, results)
    message = str(refused.value)
    assert message.startswith(f"{out / 'manifest.json'} {reason}") and "\n" not in message
    assert INVENTED_VERSION not in message


def a_page_of_ours(page: Path, out: Path) -> bytes:
    """Write a page this command wrote (so that only the manifest can stop its rewriting),
    with findings of its own; returns its bytes."""
    page.write_text(
        f"# Results: suite page-provenance (2026-01-01)\n\nSuite, made by a sweep; "
        f"{WRITTEN_BY}formation-bench report {out} --page {page} --overwrite`.\n\n"
        "<!-- findings: kept when the page is regenerated -->\nmine\n"
        "<!-- end of findings -->\n"
    )
    assert is_results_page(page)
    return page.read_bytes()


@pytest.mark.parametrize("page_exists", [False, True], ids=["new page", "existing page"])
@pytest.mark.parametrize("damage", list(DAMAGES))
def test_write_results_page_refuses_a_manifest_with_a_broken_seal(
    stored, tmp_path, damage, page_exists
):
    out = copy_of(stored, tmp_path)
    damaged, reason = DAMAGES[damage]
    damaged(out / "manifest.json")
    page = tmp_path / "page.md"
    kept = a_page_of_ours(page, out) if page_exists else None
    report_folder = tmp_path / "report"
    report_folder.mkdir()
    with pytest.raises(ManifestError, match=reason):
        write_results_page(out, page, report_folder)
    assert (page.read_bytes() if page.exists() else None) == kept
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob(".*"))


@pytest.mark.parametrize("page_exists", [False, True], ids=["new page", "existing page"])
@pytest.mark.parametrize("damage", list(DAMAGES))
def test_report_page_refuses_a_manifest_with_a_broken_seal_and_writes_nothing(
    stored, tmp_path, capsys, damage, page_exists
):
    out = copy_of(stored, tmp_path)
    manifest = out / "manifest.json"
    damaged, reason = DAMAGES[damage]
    damaged(manifest)
    page = tmp_path / "pages" / "page.md"
    page.parent.mkdir()
    if page_exists:
        a_page_of_ours(page, out)
    before = snapshot(tmp_path)
    overwrite = ["--overwrite"] if page_exists else []
    code = main(["report", str(out), "--no-figures", "--page", str(page), *overwrite])
    assert code == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"formation-bench report: error: {manifest} {reason}"), line
    assert "--rebuild-manifest" in line
    assert snapshot(tmp_path) == before  # no page, no report folder, the manifest as it was
    assert page.exists() == page_exists


def test_report_page_of_an_intact_manifest_names_its_provenance(stored, tmp_path, capsys):
    out = copy_of(stored, tmp_path)
    recorded = json.loads((out / "manifest.json").read_text())
    page = tmp_path / "page.md"
    assert main(["report", str(out), "--no-figures", "--page", str(page)]) == 0
    assert "error" not in capsys.readouterr().err
    text = page.read_text()
    assert is_results_page(page)
    assert text.startswith("# Results: suite page-provenance (")
    assert f"formation-bench {recorded['versions']['formation-bench']}" in text
    assert f"machine: {recorded['machine']['cpu_model']}" in text
    provenance = suite_provenance(out, load_results(out))
    assert provenance.name == recorded["suite"]["name"]
    assert len(provenance.commands) == 1 and f"`{provenance.commands[0]}`" in text


def test_a_sweep_command_names_its_folder_as_the_page_command_does(tmp_path, monkeypatch):
    # the sweep recorded an absolute --out; the page's own command names the same folder
    # through a link, relative to where both are run
    from formation_bench.analysis.results_page import _shown_command

    stored = tmp_path / "elsewhere" / "swept"
    stored.mkdir(parents=True)
    (tmp_path / "results").symlink_to(tmp_path / "elsewhere")
    monkeypatch.chdir(tmp_path)
    recorded = f"/opt/venv/bin/formation-bench sweep paper --out {stored} --jobs 2"
    assert _shown_command(recorded, Path("results/swept")) == (
        "formation-bench sweep paper --out results/swept --jobs 2"
    )
    # another folder, or one not on this machine, is shown as recorded
    other = f"formation-bench sweep paper --out {tmp_path / 'elsewhere'} --jobs 2"
    assert _shown_command(other, Path("results/swept")) == other
    gone = "formation-bench sweep paper --out /no/such/folder"
    assert _shown_command(gone, Path("results/swept")) == gone
