"""Fixtures shared by several test modules."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def built_site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The documentation site built from ``docs/`` as CI builds it (warnings as errors), once
    per test session: its HTML folder. Building takes about 40 s, so the tests of the built
    site share one build."""
    pytest.importorskip("sphinx")
    from test_docs_tables import DOCS, sphinx_build

    out = tmp_path_factory.mktemp("site")
    result = sphinx_build(DOCS, out)
    assert result.returncode == 0, result.stderr
    assert not (out / "html" / ".doctrees").exists()  # Sphinx's cache kept out of the site (-d)
    return out / "html"
