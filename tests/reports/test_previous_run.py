"""The run report's section on the track's previous run: each span's minimum then and now and
the wear since, most worn first."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

import pytest
from sqlalchemy import create_engine, update
from sqlalchemy.orm import Session

from catenary.maintenance.forecast import SECONDS_PER_YEAR
from catenary.storage.models import Run

from .test_reports import Page, report, spans_of

pytestmark = pytest.mark.slow

HALF_YEAR = timedelta(seconds=SECONDS_PER_YEAR / 2)


def test_run_report_shows_the_previous_run_and_the_wear_since(
    database: str, tmp_path: Path
) -> None:
    with Session(create_engine(database)) as session:  # run 1 half a year before run 2
        run_2 = session.get(Run, 2)
        assert run_2 is not None
        session.execute(
            update(Run).where(Run.id == 1).values(started_at=run_2.started_at - HALF_YEAR)
        )
        session.commit()
    out = tmp_path / "run.html"
    assert report(database, "run", "2", "-o", out).exit_code == 0
    page = Page(out.read_text())
    facts = {row[0]: row[1] for row in page.tables["previous-facts"]}
    assert facts["Previous run"].startswith("1, ")
    assert facts["Between the runs"] == "182.6 days"
    rows = page.body("previous")
    then = {
        (s.mast_from, s.mast_to, round(s.min_residual_thickness_mm, 2))
        for s in spans_of(database, 1)
    }
    now = {
        (s.mast_from, s.mast_to, round(s.min_residual_thickness_mm, 2))
        for s in spans_of(database, 2)
    }
    assert len(rows) == len(spans_of(database, 2)) > 5  # the same section: every span-wire in both
    for masts, _, _, position, before, after, wear, rate, _ in rows:
        mast_from, mast_to = masts.split(" to ")
        assert (mast_from, mast_to, float(before)) in then
        assert (mast_from, mast_to, float(after)) in now
        assert position in ("0", "1")
        assert float(wear) == pytest.approx(float(before) - float(after), abs=0.011)
        assert float(rate) == pytest.approx(float(wear) / 0.5, abs=0.011 / 0.5)
    wears = [float(r[6]) for r in rows]
    assert wears == sorted(wears, reverse=True)
    first = tmp_path / "first.html"
    assert report(database, "run", "1", "-o", first).exit_code == 0
    assert "No earlier complete run of line demo-line track 1 to compare with." in first.read_text()
