"""Plugin tests fail plugins on purpose: their failure tracebacks go to a log file in the
test's tmp directory instead of the user's (or the shared) cache folder."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _failure_log_in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    from globeview.plugins import isolation

    log = tmp_path / "globeview.log"
    monkeypatch.setattr(isolation, "failure_log_path", lambda: log)
    return log
