"""Rows the processor cannot decide are the contact wire (``selection_uncertain``), through
``catenary process`` on a small simulated run: stored with their flag, left out of the span
figures and so of the alerts, counted in the summary, exported.

The line-scan tracker is made to flag every row of a 5 m stretch and to give those rows a
worn face far wider than the run's (a thinner wire than any certain row): were they counted,
their span's minimum would be theirs and a limit between the two would raise an alert.
"""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner, Result
from sqlalchemy import Engine, select

from catenary.cli import cli
from catenary.config import load_settings
from catenary.measurement.samples import read_sample_batches, run_samples, trusted
from catenary.storage.database import session_scope
from catenary.storage.models import Run, SpanMeasurement
from catenary.storage.store import open_store
from catenary_linescan.processor.tracking import TrackedPoints, WireTracker

from ..conftest import SmallRun

UNSURE_M = (20.0, 25.0)
"""The stretch of encoder positions whose rows the tracker flags [m]."""
UNSURE_WIDTH_MM = 11.0
"""Their worn face's width in the scanning plane [mm]: 9.8 mm of a CTA120 left."""


@pytest.fixture
def unsure_tracker(monkeypatch: pytest.MonkeyPatch) -> None:
    """The tracker flags the rows of ``UNSURE_M`` as ``selection_uncertain``, as a tracker
    that cannot tell the contact wire from its messenger there does."""
    release = WireTracker._release

    def flagged(self: WireTracker, *, final: bool) -> TrackedPoints:
        points = release(self, final=final)
        unsure = (points.position_m >= UNSURE_M[0]) & (points.position_m < UNSURE_M[1])
        width = np.where(unsure, UNSURE_WIDTH_MM, points.face_mm)
        columns = {**points.columns, "selection_uncertain": unsure}
        return replace(points, face_mm=width, columns=columns)

    monkeypatch.setattr(WireTracker, "_release", flagged)


def invoke(*args: Any) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def policy(path: Path, threshold_mm: float, wire_types: set[str]) -> Path:
    path.write_text(
        "[policies.test]\ndescription = 'one local limit'\nsource = 'this test'\n\n"
        "[[policies.test.rules]]\nlevel = 'urgent'\naction = 'replace'\nscope = 'local'\n"
        f"residual_thickness_mm = {threshold_mm:.4f}\nwire_types = {sorted(wire_types)!r}\n"
    )
    return path


def test_uncertain_rows_are_stored_flagged_and_left_out_of_spans_and_alerts(
    small_run: SmallRun, engine: Engine, database_url: str, tmp_path: Path, unsure_tracker: None
) -> None:
    result = invoke(*small_run.process_args(database_url))
    assert result.exit_code == 0, result.output
    with session_scope(engine, read_only=True) as session:
        run = session.scalars(select(Run)).one()
        spans = session.scalars(select(SpanMeasurement)).all()
        path = run_samples(open_store(load_settings(database_url=database_url)), run)
        run_id = run.id
    parts = list(read_sample_batches(path))
    s = {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}

    # stored with the flag: every row of the stretch, and only those
    inside = (s["position_m"] >= UNSURE_M[0]) & (s["position_m"] < UNSURE_M[1])
    unsure = s["selection_uncertain"]
    assert np.count_nonzero(unsure) > 50
    np.testing.assert_array_equal(unsure, inside)
    counted = trusted(s) & np.isfinite(s["height_mm"]) & np.isfinite(s["stagger_mm"])
    thinnest_unsure = float(np.nanmax(s["residual_thickness_mm"][unsure]))
    thinnest_certain = float(np.nanmin(s["residual_thickness_mm"][counted]))
    assert thinnest_unsure < thinnest_certain - 0.3  # they would be every span's minimum

    # the summary counts them
    assert f"{np.count_nonzero(unsure)} not surely the contact wire" in result.output

    # span figures from the certain rows only
    assert spans
    hit = 0
    for span in spans:
        mine = counted & (s["span"] == span.span) & (s["wire"] == span.wire)
        hit += bool(np.any(unsure & (s["span"] == span.span) & (s["wire"] == span.wire)))
        assert span.samples == np.count_nonzero(mine)
        thickness = s["residual_thickness_mm"][mine]
        assert span.min_residual_thickness_mm == pytest.approx(np.nanmin(thickness), abs=1e-9)
        assert span.mean_residual_thickness_mm == pytest.approx(np.nanmean(thickness), abs=1e-9)
        assert span.height_max_mm == pytest.approx(s["height_mm"][mine].max(), abs=1e-9)
        assert span.stagger_min_mm == pytest.approx(s["stagger_mm"][mine].min(), abs=1e-9)
    assert hit  # a span holds uncertain rows

    # no alert from them: a limit between the uncertain rows and the certain ones raises
    # nothing; one just above the certain minimum raises
    types = {span.wire_type for span in spans}
    middle = 0.5 * (thinnest_unsure + thinnest_certain)
    between = policy(tmp_path / "between.toml", middle, types)
    quiet = invoke("alerts", "evaluate", "--run", run_id, "--policy-file", between, "--db",
                   database_url)  # fmt: skip
    assert quiet.exit_code == 0, quiet.output
    assert "0 new, 0 updated, 0 resolved" in quiet.output
    above = policy(tmp_path / "above.toml", thinnest_certain + 0.01, types)
    raised = invoke("alerts", "evaluate", "--run", run_id, "--policy-file", above, "--db",
                    database_url)  # fmt: skip
    assert raised.exit_code == 0, raised.output
    assert "0 new," not in raised.output

    # the export carries the flag
    output = tmp_path / "samples.csv"
    exported = invoke("export", run_id, "--what", "samples", "-o", output, "--db", database_url)
    assert exported.exit_code == 0, exported.output
    with output.open(newline="") as f:
        flags = [row["selection_uncertain"] for row in csv.DictReader(f)]
    assert flags.count("true") == np.count_nonzero(unsure)
    assert flags.count("false") == unsure.shape[0] - np.count_nonzero(unsure)

    # the run report plots the certain rows only and says how many it left out
    page = tmp_path / "run.html"
    reported = invoke("report", "run", run_id, "-o", page, "--db", database_url)
    assert reported.exit_code == 0, reported.output
    assert (
        f"{np.count_nonzero(unsure)} not surely the contact wire (selection uncertain): left out"
        in page.read_text()
    )
