"""No run is stranded: a run is pending until its track is evaluated with it, each track is
evaluated in a transaction of its own, and a track whose evaluation fails is named while the
others are evaluated (both backends)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import UTC, timedelta
from typing import Any

import pytest
from sqlalchemy import Engine, select
from sqlalchemy.orm import Session

from catenary.arrays import FloatArray
from catenary.limits import LEVELS
from catenary.maintenance.alerts import TrackFailure, evaluate_alerts, evaluate_tracks
from catenary.maintenance.jobs import JobContext, run_job
from catenary.maintenance.notifications import Channel, NotificationConfig
from catenary.plugins import PluginRegistry, hookimpl
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, AlertNotification, Run
from catenary.storage.runs import pending_runs
from catenary.wiretype import WireType

from .conftest import T0, YEAR, Fleet

NOW = T0 + 10 * YEAR
POLICY = "manufacturer-30pct"  # CTA120: critical at 8.75 mm


@dataclass(frozen=True)
class BrokenWire(WireType):
    """A third party's wire type with a bug in the worn fraction (what an alert reports)."""

    def worn_fraction(self, wear_width_mm: Any) -> FloatArray:
        raise ZeroDivisionError("area table not loaded")


class BrokenPlugin:
    @hookimpl
    def catenary_wire_types(self) -> list[WireType]:
        return [BrokenWire("BROKEN", "none", 12.9, 12.9, 120.0, 120.0)]


@pytest.fixture(scope="module")
def registry() -> PluginRegistry:
    return PluginRegistry(plugins=[("broken-wires", BrokenPlugin())])


def evaluated(session: Session) -> dict[int, bool]:
    """Each run: whether its alerts are evaluated."""
    rows = session.execute(select(Run.id, Run.alerts_evaluated_at)).all()
    return {run_id: at is not None for run_id, at in rows}


def test_a_run_is_pending_until_its_track_is_evaluated_with_it(
    engine: Engine, registry: PluginRegistry
) -> None:
    policy, wire_types = registry.limit_policies()[POLICY], registry.wire_types()
    with session_scope(engine) as session:
        fleet = Fleet(session)
        one, two = fleet.track(line="L1"), fleet.track(line="L2")
        first = fleet.run(one, T0, {3: 8.6})
        second = fleet.run(one, T0 + YEAR, {3: 8.5})
        other = fleet.run(two, T0, {1: 8.6})
        assert pending_runs(session) == [first.id, second.id, other.id]
        assert pending_runs(session, line="L2") == [other.id]
        # one run: that run only, though its track has another pending
        result = evaluate_alerts(session, policy, wire_types, run_ids=[first.id], now=NOW)
        assert result.runs == 1
        assert pending_runs(session) == [second.id, other.id]
        # every track: the rest, at the evaluation's time
        result = evaluate_alerts(session, policy, wire_types, now=NOW)
        assert result.runs == 2 and pending_runs(session) == []
        (at,) = set(session.scalars(select(Run.alerts_evaluated_at)))
        assert at == NOW
        # nothing pending, nothing new: nothing written
        again = evaluate_alerts(session, policy, wire_types, now=NOW + YEAR)
        assert (again.runs, again.new, again.updated) == (0, [], 0)
        assert set(session.scalars(select(Run.alerts_evaluated_at))) == {NOW}
        later = fleet.run(two, T0 + YEAR, {1: 8.4})
        assert pending_runs(session) == [later.id]


def test_a_failing_track_is_named_and_the_others_are_evaluated_and_committed(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        good, bad = fleet.track(line="L1"), fleet.track(line="L2", track="2")
        kept = fleet.run(good, T0, {3: 8.6})
        broken = fleet.run(bad, T0, {2: 8.0}, wire_type="BROKEN")
        later = fleet.track(line="L3")
        last = fleet.run(later, T0, {5: 8.6})
    channels = NotificationConfig((Channel("ops", "webhook", frozenset(LEVELS), {}),))
    result = evaluate_tracks(
        engine,
        registry.limit_policies()[POLICY],
        registry.wire_types(),
        now=NOW,
        notifications=channels,
    )
    assert result.failed == [TrackFailure("L2", "2", "ZeroDivisionError: area table not loaded")]
    assert str(result.failed[0]) == "line L2 track 2: ZeroDivisionError: area table not loaded"
    assert (len(result.new), result.runs) == (2, 2)  # nothing of the failed track counted
    with session_scope(engine, read_only=True) as session:
        assert evaluated(session) == {kept.id: True, broken.id: False, last.id: True}
        alerts = session.scalars(select(Alert.track_id).order_by(Alert.id)).all()
        assert alerts == [good.id, later.id]
        queued = session.scalars(select(AlertNotification.alert_id)).all()
        assert sorted(queued) == sorted(result.new)
    # the failed track's run stays pending: a later evaluation takes it up again
    again = evaluate_tracks(
        engine, registry.limit_policies()[POLICY], registry.wire_types(), run_ids=[broken.id]
    )
    assert [f.track for f in again.failed] == ["2"] and again.runs == 0


def test_the_scheduler_job_logs_a_failing_track_and_evaluates_the_others(
    engine: Engine,
    registry: PluginRegistry,
    make_settings: Any,
    caplog: pytest.LogCaptureFixture,
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        bad, good = fleet.track(line="L1"), fleet.track(line="L2")
        broken = fleet.run(bad, T0, {2: 8.0}, wire_type="BROKEN")
        kept = fleet.run(good, T0, {3: 8.6})
    settings = make_settings({"limits": {"policy": POLICY}})
    context = JobContext(settings, registry, engine, UTC, clock=lambda: NOW)
    with caplog.at_level(logging.INFO, "catenary.maintenance.jobs"):
        run_job("evaluate-alerts", {}, context, NOW - timedelta(seconds=2))
    assert caplog.messages == [
        "evaluate-alerts: line L1 track 1: ZeroDivisionError: area table not loaded "
        "(its runs stay pending)",
        "evaluate-alerts: 1 new (1 critical), 0 updated, 0 resolved",
    ]
    with session_scope(engine, read_only=True) as session:
        assert evaluated(session) == {broken.id: False, kept.id: True}
