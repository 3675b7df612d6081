"""Outputs for programs and maps: ``--format json`` of the listing commands (a list of objects,
or one object; stable keys; times ISO 8601 UTC; numbers unrounded), ``catenary runs list``,
and GeoJSON of spans and alerts placed by the mast register's coordinates."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner, Result
from sqlalchemy import Engine, select

from catenary.cli import cli
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, AlertNotification, Mast

from .conftest import T0, Fleet

LATITUDE, LONGITUDE = 48.0, 11.0
DEGREES_PER_M = 1e-5
"""The test register's masts lie due east along a parallel, this far apart per metre."""


def invoke(database_url: str, *args: str, config: Path | None = None) -> Result:
    options = ["--config", str(config)] if config else []
    return CliRunner().invoke(cli, [*options, "--db", database_url, *args], catch_exceptions=False)


def succeeded(result: Result) -> str:
    assert result.exit_code == 0, result.output
    return result.stdout


@pytest.fixture
def config(tmp_path: Path) -> Path:
    path = tmp_path / "config.toml"
    path.write_text('[limits]\npolicy = "china-maintenance-rules"\n')
    return path


@pytest.fixture
def worn(engine: Engine, database_url: str, config: Path) -> str:
    """Line L1 track 1, masts M00..M10 at 1000..1500 m, worn in spans 2 and 6; masts M00 to
    M07 have coordinates; line L2, without any, worn in span 1; alerts evaluated."""
    with session_scope(engine) as session:
        fleet = Fleet(session)
        one, two = fleet.track(line="L1"), fleet.track(line="L2")
        for mast in one.masts[:8]:
            mast.latitude = LATITUDE
            mast.longitude = LONGITUDE + DEGREES_PER_M * (mast.chainage_m - 1000.0)
        fleet.run(one, T0, {6: 8.6, 2: 7.5}, spans=[1, 2, 6, 7, 8])
        fleet.run(two, T0, {1: 8.6})
    succeeded(invoke(database_url, "alerts", "evaluate", "--all", config=config))
    return database_url


def test_alerts_list_as_json_is_every_alert_unrounded(worn: str, engine: Engine) -> None:
    listed = json.loads(succeeded(invoke(worn, "alerts", "list", "--format", "json")))
    with session_scope(engine, read_only=True) as session:
        stored = {a.id: a for a in session.scalars(select(Alert))}
        assert {a["id"] for a in listed} == set(stored) and stored
        for record in listed:
            alert = stored[record["id"]]
            assert record["value"] == alert.value and record["threshold"] == alert.threshold
            assert record["line"] == alert.track.line.code and record["wire_position"] == alert.wire
            assert record["raised_at"].endswith("+00:00")
            assert record["resolved_at"] is None
    assert list(listed[0])[:4] == ["id", "line", "track", "wire_position"]


def test_alerts_as_geojson_follow_the_masts_and_leave_out_the_unplaced(worn: str) -> None:
    result = invoke(worn, "alerts", "list", "--format", "geojson")
    collection = json.loads(succeeded(result))
    assert collection["type"] == "FeatureCollection"
    # span 2 (1100-1150 m) and 6 (1300-1350 m) of L1 are placed; L2's alert is not
    assert result.stderr == "1 alert(s) left out: no mast coordinates there\n"
    features = collection["features"]
    assert {f["properties"]["mast_from"] for f in features} == {"M02", "M06"}
    for f in features:
        start_m = f["properties"]["start_chainage_m"]
        assert f["geometry"]["type"] == "LineString"
        (x0, y0), (x1, y1) = f["geometry"]["coordinates"]
        assert x0 == pytest.approx(LONGITUDE + DEGREES_PER_M * (start_m - 1000.0), abs=1e-12)
        assert x1 - x0 == pytest.approx(50.0 * DEGREES_PER_M, abs=1e-12)
        assert y0 == y1 == LATITUDE


def test_alerts_geojson_written_to_a_file(worn: str, tmp_path: Path) -> None:
    out = tmp_path / "alerts.geojson"
    result = invoke(worn, "alerts", "list", "--line", "L1", "-o", str(out))
    written = len(json.loads(out.read_text())["features"])
    assert succeeded(result) == f"{written} alert(s) written to {out}\n" and written >= 2


def test_alerts_geojson_without_any_coordinates_is_refused(worn: str, tmp_path: Path) -> None:
    out = tmp_path / "alerts.geojson"
    result = invoke(worn, "alerts", "list", "--line", "L2", "-o", str(out))
    assert result.exit_code == 1
    assert result.output.strip().splitlines() == [
        "Error: no mast of the alerts' tracks has coordinates (latitude, longitude; FORMATS.md, "
        "Mast register): no GeoJSON"
    ]
    assert not out.exists()


def test_spans_as_geojson_run_from_mast_to_mast(worn: str, tmp_path: Path) -> None:
    out = tmp_path / "spans.geojson"
    result = invoke(worn, "export", "1", "--what", "spans", "-o", str(out))
    assert succeeded(result) == f"3 spans of run 1 written to {out}\n"
    # M07-M08 and M08-M09: M08 has no coordinates
    assert result.stderr == "2 spans left out: their masts have no coordinates\n"
    features = json.loads(out.read_text())["features"]
    assert [f["properties"]["span"] for f in features] == [1, 2, 6]
    first = features[0]
    assert first["geometry"]["coordinates"] == [
        [LONGITUDE + DEGREES_PER_M * 50.0, LATITUDE],
        [LONGITUDE + DEGREES_PER_M * 100.0, LATITUDE],
    ]
    assert first["properties"]["min_residual_thickness_mm"] == 12.5


def test_spans_geojson_of_a_register_without_coordinates_is_refused(
    worn: str, tmp_path: Path
) -> None:
    out = tmp_path / "spans.geojson"
    result = invoke(worn, "export", "2", "--what", "spans", "-o", str(out))
    assert result.exit_code == 1
    assert result.output.strip().splitlines() == [
        f"Error: {out}: the mast register of run 2's track has no coordinates (latitude, "
        "longitude; FORMATS.md, Mast register)"
    ]
    assert not out.exists()


def test_runs_list(worn: str) -> None:
    runs: list[dict[str, Any]] = json.loads(
        succeeded(invoke(worn, "runs", "list", "--format", "json"))
    )
    assert [r["id"] for r in runs] == [1, 2]
    assert list(runs[0]) == [
        "id",
        "uuid",
        "line",
        "track",
        "direction",
        "vehicle",
        "started_at",
        "scans",
        "status",
        "processing_uuid",
        "processed_at",
        "length_m",
    ]
    assert runs[0]["started_at"] == T0.isoformat() == "2020-01-06T09:00:00+00:00"
    assert (runs[0]["line"], runs[1]["line"]) == ("L1", "L2")
    only = json.loads(succeeded(invoke(worn, "runs", "list", "--line", "L2", "--format", "json")))
    assert [r["id"] for r in only] == [2]
    text = succeeded(invoke(worn, "runs", "list", "--line", "L1", "--track", "1")).splitlines()
    assert len(text) == 2 and text[0].split()[0] == "1" and text[-1] == "1 run(s)"
    assert invoke(worn, "runs", "list", "--track", "1").exit_code == 2  # --track needs --line


def test_notify_status_as_json(worn: str, engine: Engine) -> None:
    assert json.loads(succeeded(invoke(worn, "notify", "status", "--format", "json"))) == []
    with session_scope(engine) as session:
        alert = session.scalars(select(Alert).order_by(Alert.id)).first()
        assert alert is not None
        session.add(AlertNotification(alert=alert, notifier="mail", last_error="refused"))
    (row,) = json.loads(succeeded(invoke(worn, "notify", "status", "--format", "json")))
    assert row["alert_id"] == 1 and row["channel"] == "mail" and row["status"] == "pending"
    assert row["channel_configured"] is False and row["last_error"] == "refused"


def test_db_current_and_plugins_as_json(worn: str) -> None:
    current = json.loads(succeeded(invoke(worn, "db", "current", "--format", "json")))
    assert current["revision"] == current["head"] and current["at_head"] is True
    assert set(current) == {"database", "revision", "head", "at_head", "known"}
    plugins = json.loads(succeeded(CliRunner().invoke(cli, ["plugins", "--format", "json"])))
    by_name = {p["plugin"]: p["registers"] for p in plugins}
    assert "run" in by_name["reports"]["reporter"]


def test_masts_without_coordinates_stay_so(engine: Engine, worn: str) -> None:
    """The fixture's register: the last three masts of L1 are not placed."""
    with session_scope(engine, read_only=True) as session:
        unplaced = session.scalars(select(Mast.code).where(Mast.latitude.is_(None))).all()
    assert len(unplaced) == 3 + 11
