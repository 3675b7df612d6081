"""``catenary demo`` end to end on a short section, into a fresh SQLite database."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from sqlalchemy import create_engine, select
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.measurement.runfile import open_run
from catenary.storage.models import RigCalibration, Run
from catenary_linescan.rig import read_rig


@pytest.mark.slow
def test_demo_simulates_calibrates_processes_and_reports(tmp_path: Path) -> None:
    database = tmp_path / "demo.sqlite"
    out = tmp_path / "demo"
    args = ["--db", f"sqlite:///{database}", "demo", "--out", str(out), "--length-m", "40"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    with open_run(out / "run.h5") as run:
        assert run.header.scans > 2000
        assert sorted(run.header.camera_pixels) == ["cam1", "cam2", "cam3", "cam4"]
    assert max(c.reprojection_rms_px for c in read_rig(out / "rig.toml").cameras.values()) < 0.3
    with Session(create_engine(f"sqlite:///{database}")) as session:
        stored = session.scalars(select(RigCalibration)).one()
        assert stored.vehicle.name == "demo-rig"
        assert stored.content_toml == (out / "rig.toml").read_text()
        run = session.scalars(select(Run)).one()
        assert run.rig_calibration_id == stored.id and run.status == "complete"
        spans = len(run.span_measurements)
    assert spans >= 1
    assert (
        "<svg" in (out / "report.html").read_text() or "base64" in (out / "report.html").read_text()
    )
    report = (out / "spans.csv").read_text().splitlines()
    assert report[0].startswith('"span","mast_from"') and len(report) == spans + 1
    assert f"database          sqlite:///{database} (run 1)" in result.output
    again = CliRunner().invoke(cli, args)  # a new recording (its own completion time): a new run
    assert again.exit_code == 0, again.output
    assert "stored as run 2" in again.output
