"""Known incompatibilities between installed libraries are reported as such, not as failures.

An adapter raises :class:`LibraryIncompatibility` when an adapted library fails in a
documented way with the installed version of another (nevergrad 1.0.12's meta-models
with numpy >= 2.4); the test that meets it is reported as an expected failure with the
adapter's explanation, and passes again once the libraries agree.
"""

from __future__ import annotations

import pytest

from formation_bench.optimizers.adapters.common import LibraryIncompatibility


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if call.excinfo is not None and call.excinfo.errisinstance(LibraryIncompatibility):
        report.outcome = "skipped"
        report.wasxfail = f"known library incompatibility: {call.excinfo.value}"
    return report
