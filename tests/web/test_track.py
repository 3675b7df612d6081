"""The track view's data (``GET /api/v1/tracks/profile``) and page (``/track``), over a
synthetic 100 km track with two runs whose samples files are in the service's store."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sqlalchemy import Engine

from catenary.measurement.samples import SampleWriter
from catenary.plugins import PluginRegistry
from catenary.positions import positions_along
from catenary.storage.database import session_scope
from catenary.storage.models import Line, Mast, Run, SpanMeasurement, Track
from catenary.storage.store import samples_key
from catenary.web.app import create_app
from catenary.wiretype import STANDARD_WORN_FRACTION
from tests.conftest import Build
from tests.web.conftest import Web

LENGTH_M = 100_000.0
STEP_M = 1.0  # one scan a metre
MAST_EVERY_M = 500.0
OVERLAP_M = (5_000.0, 5_500.0)  # span 10: a second contact wire (an overlap)
HOT_SPOT_M = 42_123.0  # the latest run's thinnest sample
HOT_SPOT_MM = 8.5
FITTING_M = (30_000.0, 30_010.0)  # no wear width measured: no residual thickness
THICKNESS_MM = 11.0


@dataclass(frozen=True)
class Fleet:
    """The track's runs (ids): the latest and the one before it, and a run of another track."""

    latest: int
    previous: int
    other: int


def samples(position_of: dict[int, int], seed: int, hot_spot: bool) -> dict[str, Any]:
    """The samples file's columns of a run along the whole track: the wire at position 0
    (``position_of``: wire number -> position) everywhere, the other one in the overlap only,
    100 mm higher."""
    rng = np.random.default_rng(seed)
    chainage = np.arange(0.0, LENGTH_M, STEP_M) + 0.25
    wire_of = {position: wire for wire, position in position_of.items()}
    overlap = chainage[(chainage >= OVERLAP_M[0]) & (chainage < OVERLAP_M[1])]
    all_chainage = np.concatenate([chainage, overlap])
    position = np.concatenate([np.zeros(chainage.shape), np.ones(overlap.shape)])
    wire = np.where(position == 0, wire_of[0], wire_of[1]).astype(np.int32)
    order = np.lexsort((wire, all_chainage))
    all_chainage, wire, position = all_chainage[order], wire[order], position[order]
    rows = all_chainage.shape[0]
    thickness = THICKNESS_MM + rng.uniform(-0.2, 0.2, rows)
    thickness[(all_chainage >= FITTING_M[0]) & (all_chainage < FITTING_M[1])] = np.nan
    if hot_spot:
        thickness[np.flatnonzero(np.isclose(all_chainage, HOT_SPOT_M + 0.25))[0]] = HOT_SPOT_MM
    return {
        "scan": np.arange(rows),
        "position_m": all_chainage,
        "chainage_m": all_chainage,
        "wire": wire,
        "height_mm": 5300.0 + 100.0 * position + rng.uniform(-5.0, 5.0, rows),
        "stagger_mm": rng.uniform(-200.0, 200.0, rows),
        "wear_width_mm": np.full(rows, 6.0),
        "residual_thickness_mm": thickness,
        "selection_uncertain": np.zeros(rows, dtype=bool),
        "cameras": np.full(rows, 3, dtype=np.int16),
        "span": np.floor(all_chainage / MAST_EVERY_M).astype(np.int32),
        "vehicle_fault": np.zeros(rows, dtype=bool),
    }


def store_run(web: Web, tmp_path: Path, run: Run, columns: dict[str, Any]) -> None:
    """Write the run's samples file and put it in the service's store."""
    assert run.processing is not None
    path = tmp_path / f"{run.processing.uuid}.parquet"
    with SampleWriter(path) as writer:
        writer.write(columns)
    key = samples_key(run.line.code, run.track.code if run.track else "", run.uuid, path.stem)
    web.app.state.web.store.put_file(path, key)
    run.processing.samples_key = key


def span_rows(run: Run, position_of: dict[int, int]) -> list[SpanMeasurement]:
    """The run's span measurements: one a span for position 0, and the overlap's second."""
    rows = []
    for span in range(int(LENGTH_M / MAST_EVERY_M)):
        start = span * MAST_EVERY_M
        inside = [0, 1] if start == OVERLAP_M[0] else [0]
        for position in inside:
            wire = next(w for w, p in position_of.items() if p == position)
            rows.append(
                Build.span(
                    run,
                    span,
                    track_id=run.track_id,
                    mast_from=f"M{span}",
                    mast_to=f"M{span + 1}",
                    start_chainage_m=start,
                    end_chainage_m=start + MAST_EVERY_M,
                    wire=wire,
                    wire_position=position,
                )
            )
    return rows


@pytest.fixture
def fleet(web: Web, engine: Engine, build: type[Build], tmp_path: Path) -> Fleet:
    """Line L1 track 1/A along 100 km with a mast each 500 m; two runs of it (the later
    numbers its wires the other way round) and a run of another track; three alerts."""
    with session_scope(engine) as session:
        first = build.run(session)  # line L100 track 1: another track
        track = Track(line=Line(code="L1"), code="1/A")
        track.masts = [
            Mast(
                code=f"M{k}",
                chainage_m=k * MAST_EVERY_M,
                wire_type="CTA120",
                design_stagger_mm=200.0 if k % 2 else -200.0,
                design_height_mm=5300.0,
            )
            for k in range(int(LENGTH_M / MAST_EVERY_M) + 1)
        ]
        session.add(track)
        session.flush()
        made = {}
        for name, days, positions, seed in (
            ("previous", 0, {1: 0, 0: 1}, 1),
            ("latest", 30, {0: 0, 1: 1}, 2),
        ):
            run = build.run(
                session,
                line=track.line,
                track=track,
                vehicle=first.vehicle,
                rig_calibration=first.rig_calibration,
                source_sha256=f"{seed}" * 64,
                started_at=build.T0 + timedelta(days=days),
                status="complete",
            )
            store_run(web, tmp_path, run, samples(positions, seed, name == "latest"))
            session.add_all(span_rows(run, positions))
            made[name] = run.id
        session.add_all(
            [
                build.alert(
                    track,
                    "in",
                    level="critical",
                    start_chainage_m=42_000.0,
                    end_chainage_m=42_500.0,
                    mast_from="M84",
                    mast_to="M85",
                ),
                build.alert(track, "out", start_chainage_m=80_000.0, end_chainage_m=80_500.0),
                build.alert(
                    track,
                    "resolved",
                    status="resolved",
                    start_chainage_m=42_000.0,
                    end_chainage_m=42_500.0,
                ),
            ]
        )
        return Fleet(made["latest"], made["previous"], first.id)


PROFILE = "/api/v1/tracks/profile"


def profile(web: Web, **params: Any) -> dict[str, Any]:
    answer = web.api("vera").get(PROFILE, params={"line": "L1", "track": "1/A", **params})
    assert answer.status_code == 200, answer.text
    body: dict[str, Any] = answer.json()
    return body


def wire(run: dict[str, Any], position: int) -> dict[str, Any]:
    (found,) = [w for w in run["wires"] if w["wire_position"] == position]
    return found


@pytest.mark.parametrize(
    ("from_m", "to_m", "columns", "level_m", "bin_m", "resolution"),
    [
        (0.0, LENGTH_M, 1000, 100.0, 100.0, "100 m"),
        (0.0, LENGTH_M, 1200, 10.0, 80.0, "10 m"),  # 83 m a column: 8 bins of 10 m as one
        (40_000.0, 50_000.0, 1000, 10.0, 10.0, "10 m"),
        (41_000.0, 43_000.0, 1200, 1.0, 1.0, "1 m"),
        (42_000.0, 42_500.0, 1200, None, None, "raw"),
    ],
)
def test_the_coarsest_level_that_fills_the_screen_and_raw_samples_below_a_kilometre(
    web: Web,
    fleet: Fleet,
    from_m: float,
    to_m: float,
    columns: int,
    level_m: float | None,
    bin_m: float | None,
    resolution: str,
) -> None:
    body = profile(web, from_m=from_m, to_m=to_m, columns=columns)
    assert (body["level_m"], body["bin_m"], body["resolution"]) == (level_m, bin_m, resolution)
    assert (body["from_m"], body["to_m"], body["columns"]) == (from_m, to_m, columns)
    latest = wire(body["latest"], 0)
    chainage = np.array(latest["chainage_m"])
    # every bin of the window, in order, and nothing outside it
    step = STEP_M if bin_m is None else bin_m
    assert chainage.shape[0] == pytest.approx((to_m - from_m) / step, abs=1.0)
    assert np.all(np.diff(chainage) > 0)
    assert chainage[0] >= from_m - step and chainage[-1] <= to_m
    low = np.array(latest["min_residual_thickness_mm"], dtype=float)
    # the hot spot is in its bin (never averaged away), to the 0.001 mm sent
    at = int(np.searchsorted(chainage, HOT_SPOT_M + 0.25, side="right")) - 1
    assert low[at] == pytest.approx(HOT_SPOT_MM, abs=0.001)
    assert np.nanmin(np.delete(low, at)) >= THICKNESS_MM - 0.2 - 0.001
    if level_m is None:
        assert latest["max_residual_thickness_mm"] is None and latest["stagger_max_mm"] is None
    else:
        high = np.array(latest["max_residual_thickness_mm"], dtype=float)
        assert np.all(high >= low) and np.nanmax(high) <= THICKNESS_MM + 0.2 + 0.001


def test_the_previous_run_beside_the_latest_per_wire_position(web: Web, fleet: Fleet) -> None:
    body = profile(web, from_m=4_000.0, to_m=7_000.0, columns=1000)
    assert body["latest"]["id"] == fleet.latest and body["previous"]["id"] == fleet.previous
    for run in (body["latest"], body["previous"]):
        assert [w["wire_position"] for w in run["wires"]] == [0, 1]
        # position 1 is the overlap's second wire, whatever the run numbers it: 100 mm higher
        overlap = wire(run, 1)
        assert body["bin_m"] == 3.0  # 3 m a column: 3 bins of 1 m as one
        assert min(overlap["chainage_m"]) >= OVERLAP_M[0] - 3.0
        assert max(overlap["chainage_m"]) < OVERLAP_M[1]
        assert min(overlap["height_min_mm"]) >= 5395.0 - 0.001
        assert max(wire(run, 0)["height_max_mm"]) <= 5305.0 + 0.001
    # the earlier run has no hot spot
    assert min(wire(body["previous"], 0)["min_residual_thickness_mm"]) > THICKNESS_MM - 0.21
    # an earlier run asked for has no run before it
    earlier = profile(web, from_m=4_000.0, to_m=7_000.0, run=str(fleet.previous))
    assert earlier["latest"]["id"] == fleet.previous and earlier["previous"] is None


def test_masts_and_alerts_of_the_window_only(web: Web, fleet: Fleet) -> None:
    body = profile(web, from_m=41_800.0, to_m=43_200.0)
    masts = body["masts"]
    # the masts inside and the nearest either side (the spans at the window's edges)
    assert masts["mast"] == ["M83", "M84", "M85", "M86", "M87"]
    assert masts["chainage_m"] == [41_500.0, 42_000.0, 42_500.0, 43_000.0, 43_500.0]
    assert masts["design_stagger_mm"] == [200.0, -200.0, 200.0, -200.0, 200.0]
    assert masts["design_height_mm"] == [5300.0] * 5
    alerts = body["alerts"]
    assert alerts["level"] == ["critical"] and alerts["status"] == ["open"]
    assert (alerts["start_chainage_m"], alerts["end_chainage_m"]) == ([42_000.0], [42_500.0])
    assert (alerts["mast_from"], alerts["wire_position"]) == (["M84"], [0])
    assert profile(web, from_m=60_000.0, to_m=61_000.0)["alerts"]["id"] == []


def test_the_wire_types_standard_limit_without_a_policy_and_the_geometry_limits_of_one(
    web: Web, fleet: Fleet, make_settings: Any
) -> None:
    body = profile(web, from_m=0.0, to_m=2_000.0)
    cta120 = PluginRegistry().wire_types()["CTA120"]
    standard = float(
        cta120.residual_thickness_mm(cta120.wear_width_for_worn_fraction(STANDARD_WORN_FRACTION))
    )
    (limit,) = body["limits"]["wear"]
    assert body["limits"]["policy"] == "standard-limits"
    assert (limit["wire_type"], limit["level"]) == ("CTA120", "critical")
    assert limit["residual_thickness_mm"] == pytest.approx(standard, abs=0.001)
    assert body["limits"]["geometry"] == []

    app = create_app(make_settings({"limits": {"policy": "db-ril-997"}}))
    try:
        configured = Web(app, web.tokens)
        limits = profile(configured, from_m=0.0, to_m=2_000.0)["limits"]
    finally:
        app.state.web.engine.dispose()
    assert limits["policy"] == "db-ril-997"
    assert {w["level"] for w in limits["wear"]} == {"urgent"}  # 20 % loss: every wire type
    checks = {(g["check"], g["max_mm"], g["max_abs_mm"]) for g in limits["geometry"]}
    assert ("height", 6500.0, None) in checks and ("stagger", None, 400.0) in checks


def test_the_whole_track_by_default_and_a_track_without_runs(
    web: Web, fleet: Fleet, engine: Engine
) -> None:
    body = profile(web)
    assert (body["from_m"], body["to_m"]) == (0.0, LENGTH_M)
    assert body["extent_m"] == [0.0, LENGTH_M]
    with session_scope(engine) as session:
        bare = Track(line=Line(code="L2"), code="2")
        bare.masts = [Mast(code="A", chainage_m=100.0, wire_type="X-1")]
        session.add(bare)
    answer = web.api("vera").get(PROFILE, params={"line": "L2", "track": "2", "to_m": 900.0})
    assert answer.status_code == 200, answer.text
    empty = answer.json()
    assert empty["latest"] is None and empty["previous"] is None
    assert empty["from_m"] == 0.0 and empty["extent_m"] is None  # one mast: no extent
    assert empty["masts"]["mast"] == ["A"]
    assert empty["limits"]["unknown_wire_types"] == ["X-1"] and empty["limits"]["wear"] == []


def test_a_run_without_its_samples_file_says_so(web: Web, fleet: Fleet, engine: Engine) -> None:
    with session_scope(engine) as session:
        run = session.get(Run, fleet.previous)
        assert run is not None and run.processing is not None
        web.app.state.web.store.delete(run.processing.samples_key or "")
    body = profile(web, from_m=0.0, to_m=2_000.0)
    assert body["previous"]["wires"] == [] and "samples" in body["previous"]["problem"]
    assert body["latest"]["problem"] is None and body["latest"]["wires"]


@pytest.mark.parametrize(
    ("params", "status", "message"),
    [
        ({"from_m": 10.0, "to_m": 5.0}, 422, "must be below"),
        ({"from_m": 5.0, "to_m": 5.0}, 422, "must be below"),
        ({"columns": 50}, 422, "columns"),
        ({"columns": 5000}, 422, "columns"),
        ({"from_m": "nan"}, 422, "from_m"),
        ({"to_m": "far"}, 422, "to_m"),
        ({"track": "9"}, 404, "no track '9' on line 'L1'"),
        ({"line": None}, 422, "line"),
        ({"run": "99999"}, 404, "no run 99999"),
    ],
)
def test_bad_input_is_one_clear_error(
    web: Web, fleet: Fleet, params: dict[str, Any], status: int, message: str
) -> None:
    query = {k: v for k, v in {"line": "L1", "track": "1/A", **params}.items() if v is not None}
    answer = web.api("vera").get(PROFILE, params=query)
    assert answer.status_code == status
    assert message in answer.json()["error"] and "Traceback" not in answer.text


def test_a_run_of_another_track_is_not_found(web: Web, fleet: Fleet) -> None:
    answer = web.api("vera").get(
        PROFILE, params={"line": "L1", "track": "1/A", "run": str(fleet.other)}
    )
    assert answer.status_code == 404 and "is not on line 'L1' track '1/A'" in answer.text


def test_a_viewer_reads_it_with_a_token_or_the_session_cookie_and_nobody_else(
    web: Web, fleet: Fleet
) -> None:
    params = {"line": "L1", "track": "1/A", "from_m": 0.0, "to_m": 2_000.0}
    assert web.anonymous().get(PROFILE, params=params).status_code == 401
    assert web.client("vera").get(PROFILE, params=params).status_code == 200  # no CSRF header


SRC = re.compile(r'<(?:script|link)\b[^>]*\b(?:src|href)="([^"]*)"', re.IGNORECASE)


def test_the_page_links_the_vendored_chart_library_and_nothing_outside(
    web: Web, fleet: Fleet
) -> None:
    client = web.client("vera")
    page = client.get("/track", params={"line": "L1", "track": "1/A", "from_m": 100.0})
    assert page.status_code == 200
    links = SRC.findall(page.text)
    assert "/static/vendor/uPlot-1.6.32.iife.min.js" in links
    assert "/static/vendor/uPlot-1.6.32.min.css" in links and "/static/track.js" in links
    assert not [link for link in links if "//" in link or link.startswith("http")]
    for link in links:
        assert link == "data:," or client.get(link).status_code == 200, link
    block = re.search(r'<script type="application/json" id="track-view">(.*?)</script>', page.text)
    assert block is not None
    view = json.loads(block.group(1))
    assert (view["line"], view["track"], view["from_m"], view["to_m"]) == ("L1", "1/A", 100.0, None)
    assert view["profile_url"] == PROFILE
    # the runs shown, and no other inline script
    assert f'href="/runs/{fleet.latest}"' in page.text
    assert f'href="/runs/{fleet.previous}"' in page.text
    assert len(re.findall(r"<script\b(?![^>]*\bsrc=)", page.text)) == 1


def test_the_page_escapes_codes_and_refuses_an_unknown_track(web: Web, engine: Engine) -> None:
    with session_scope(engine) as session:
        session.add(Track(line=Line(code="L</script><b>"), code="1"))
    client = web.client("vera")
    page = client.get("/track", params={"line": "L</script><b>", "track": "1"})
    assert page.status_code == 200
    assert "</script><b>" not in page.text and "L\\u003c/script\\u003e" in page.text
    missing = client.get("/track", params={"line": "L1", "track": "nope"})
    assert missing.status_code == 404 and "no track" in missing.text
    anonymous = web.anonymous().get("/track", params={"line": "L1", "track": "1"})
    assert anonymous.status_code == 303 and anonymous.headers["location"].startswith("/sign-in")


def test_a_backwards_window_in_the_address_shows_the_whole_track(web: Web, fleet: Fleet) -> None:
    page = web.client("vera").get(
        "/track", params={"line": "L1", "track": "1/A", "from_m": 9.0, "to_m": 1.0}
    )
    view = re.search(r'id="track-view">(.*?)</script>', page.text)
    assert view is not None and json.loads(view.group(1))["from_m"] is None


def test_positions_along_the_chainage_from_the_span_measurements() -> None:
    # wire 3 is position 1 in the span from 100 m and position 0 from 150 m on; wire 4 has none
    span_start_m = np.array([100.0, 150.0, 100.0])
    span_wire = np.array([5, 3, 3])
    span_position = np.array([0, 0, 1])
    chainage_m = np.array([90.0, 100.0, 149.9, 150.0, 400.0, 120.0, 120.0])
    wire = np.array([3, 3, 3, 3, 3, 5, 4])
    found = positions_along(chainage_m, wire, span_start_m, span_wire, span_position)
    assert found.tolist() == [1, 1, 1, 0, 0, 0, -1]


def test_no_value_is_null_and_the_rest_of_the_point_is_kept(web: Web, fleet: Fleet) -> None:
    for from_m, to_m, columns in ((29_900.0, 30_100.0, 1000), (29_000.0, 31_000.0, 2000)):
        body = profile(web, from_m=from_m, to_m=to_m, columns=columns)
        latest = wire(body["latest"], 0)
        chainage = np.array(latest["chainage_m"])
        inside = (chainage >= FITTING_M[0]) & (chainage < FITTING_M[1])
        assert inside.sum() == 10  # a sample or 1 m bin a metre
        thickness = latest["min_residual_thickness_mm"]
        assert all(thickness[i] is None for i in np.flatnonzero(inside))
        assert all(thickness[i] is not None for i in np.flatnonzero(~inside))
        assert None not in latest["height_min_mm"]
