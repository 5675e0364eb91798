"""Under CI=true a skipped test fails: a CI machine without the browser, systemd-analyze, journald or root must
not pass by proving nothing. Locally a skip stays a skip (the summary line `-ra` prints says why).

Registered by tests/conftest.py; `scripts/setup.sh` installs what the skipping tests need.
"""
from __future__ import annotations

import os

import pytest


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


def _reason(longrepr: object) -> str:
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2]).removeprefix("Skipped: ")
    return str(longrepr)


def _fail(report, what: str) -> None:
    report.outcome = "failed"
    report.longrepr = (f"{what} skipped under CI=true, where every test must run ({_reason(report.longrepr)}); "
                       "install what it needs (scripts/setup.sh)")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if in_ci() and report.skipped and not hasattr(report, "wasxfail"):
        _fail(report, item.nodeid)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    report = outcome.get_result()
    if in_ci() and report.skipped:  # a module-level importorskip or skip(allow_module_level=True)
        _fail(report, collector.nodeid)
