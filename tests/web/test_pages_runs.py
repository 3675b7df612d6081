"""The runs pages: the list with its filters, a run's facts (alignment, vehicle, calibration,
processings, spans), 404 for an unknown run, and the run report of a processed run."""

from __future__ import annotations

import re
from datetime import timedelta
from html import unescape
from pathlib import Path

from click.testing import CliRunner
from sqlalchemy import Engine

from catenary.cli import cli
from catenary.storage.database import session_scope
from catenary.storage.models import Line, Track
from tests.conftest import Build, SmallRun
from tests.web.conftest import Web


def _runs(engine: Engine, build: type[Build]) -> dict[str, object]:
    """A run of L100 track 1 aligned to the register, processed twice, with three spans (two
    wires in one); and a run of line ``<b>L2</b>``."""
    with session_scope(engine) as session:
        run = build.run(
            session,
            chainage_aligned=True,
            alignment_matched=7,
            alignment_rms_m=0.125,
            encoder_scale=1.0 / 1.0025,
            chainage_offset_m=1000.5,
            length_m=150.0,
        )
        session.add(build.processing(run, processed_at=build.T0 - timedelta(days=1)))
        session.add_all(
            [build.span(run, 0), build.span(run, 1), build.span(run, 1, wire=1, wire_position=1)]
        )
        line = Line(code="<b>L2</b>")
        other = build.run(
            session,
            line=line,
            track=Track(line=line, code="1"),
            vehicle=run.vehicle,
            rig_calibration=run.rig_calibration,
            source_sha256="e" * 64,
            started_at=build.T0 + timedelta(days=9),
        )
        return {"id": run.id, "uuid": run.uuid, "other": other.id, "latest": run.processing.uuid}


def test_the_runs_list_newest_first_and_filtered(
    web: Web, engine: Engine, build: type[Build]
) -> None:
    runs = _runs(engine, build)
    client = web.client("vera")
    html = client.get("/runs").text
    assert [int(i) for i in re.findall(r'<tr id="run-(\d+)"', html)] == [runs["other"], runs["id"]]
    assert "&lt;b&gt;L2&lt;/b&gt;" in html and "<b>L2</b>" not in html
    assert f'<a href="/runs/{runs["id"]}">' in html and "demo-rig" in html
    assert "2 run(s)" in html
    only = client.get("/runs?line=L100&track=1").text
    assert re.findall(r'<tr id="run-(\d+)"', only) == [str(runs["id"])]
    assert "No run matches" in client.get("/runs?line=L9").text


def test_a_run_by_id_uuid_or_prefix(web: Web, engine: Engine, build: type[Build]) -> None:
    runs = _runs(engine, build)
    client = web.client("vera")
    for reference in (str(runs["id"]), str(runs["uuid"]), str(runs["uuid"])[:8]):
        page = client.get(f"/runs/{reference}")
        assert page.status_code == 200
        html = unescape(page.text)
        assert f"Run {runs['id']}: line L100, track 1" in html
    assert "aligned to the register through 7 registration points" in html
    assert "(residual RMS 0.12 m, encoder error +0.250%)" in html
    assert "2 (3 span-wires) in the latest processing" in html
    assert "demo-rig" in html and "3,900 mm" in html and "demo version 1" in html
    rows = re.findall(r"<tr( class=\"latest\")?>\s*<td><code>(\w+)</code>", html)
    assert [(bool(latest), uuid) for latest, uuid in rows] == [
        (False, rows[0][1]),
        (True, str(runs["latest"])[:8]),
    ]
    assert "/track?line=L100&amp;track=1" in page.text
    assert f'href="/runs/{runs["id"]}/report"' in page.text
    latest = client.get("/runs/latest")
    assert f"Run {runs['other']}:" in latest.text  # processed last


def test_an_unknown_run_is_a_clear_404(web: Web, engine: Engine, build: type[Build]) -> None:
    _runs(engine, build)
    client = web.client("vera")
    missing = client.get("/runs/999999")
    assert missing.status_code == 404 and "no run 999999 in the database" in missing.text
    bad = client.get("/runs/xyz")
    assert bad.status_code == 404 and "give a run id" in bad.text
    assert client.get("/runs/999999/report").status_code == 404


def test_the_run_report_of_a_processed_run(
    web: Web, small_run: SmallRun, database_url: str, tmp_path: Path
) -> None:
    processed = CliRunner().invoke(cli, small_run.process_args(database_url))
    assert processed.exit_code == 0, processed.output
    client = web.client("vera")
    report = client.get("/runs/latest/report")
    assert report.status_code == 200 and report.headers["content-type"].startswith("text/html")
    assert "Run 1: line demo-line, track 1" in unescape(report.text)
    assert "<svg" in report.text and 'src="http' not in report.text
    page = client.get("/runs/1").text
    alignment = page[
        page.index('id="alignment"') : page.index("</td>", page.index('id="alignment"'))
    ]
    assert "start chainage + encoder distance" in alignment or "registration points" in alignment


def test_the_runs_api_pages(web: Web, engine: Engine, build: type[Build]) -> None:
    with session_scope(engine) as session:
        first = build.run(session)
        for k in range(1, 5):
            build.run(
                session,
                line=first.line,
                track=first.track,
                vehicle=first.vehicle,
                rig_calibration=first.rig_calibration,
                source_sha256=f"{k:064x}",
            )
    api = web.api("vera")
    everything = [r["id"] for r in api.get("/api/v1/runs").json()]
    pages = [api.get(f"/api/v1/runs?limit=2&offset={o}").json() for o in (0, 2, 4)]
    assert [r["id"] for page in pages for r in page] == everything and len(everything) == 5
    assert api.get("/api/v1/runs?limit=0").status_code == 422
