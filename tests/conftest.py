"""Fixtures for every test: each test runs with its own data directory and no user config."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def isolated_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Point catenary at a per-test data dir and hide the user's config and database."""
    data_dir = tmp_path / "catenary-data"
    monkeypatch.setenv("CATENARY_DATA_DIR", str(data_dir))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg-config"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg-data"))
    monkeypatch.delenv("CATENARY_DATABASE_URL", raising=False)
    monkeypatch.delenv("CATENARY_CONFIG", raising=False)
    monkeypatch.delenv("CATENARY_DISABLE_PLUGIN_AUTOLOAD", raising=False)
    return data_dir
