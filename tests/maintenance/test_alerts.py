"""The alert evaluation on both backends: rules, life cycle, forecasts, anchor sections.

Policies are the presets; for CTA120 (A = B = 12.90 mm): ``manufacturer-30pct`` is critical at
8.75 mm (30 % loss, inclusive), ``china-maintenance-rules`` plans at an anchor-section average
below 9.26 mm (25 %, exclusive), is urgent below 8.75 mm and critical at 7.77 mm (40 %).
"""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

import pytest
from sqlalchemy import Engine, select
from sqlalchemy.orm import Session

from catenary.limits import thresholds
from catenary.maintenance.actions import record_maintenance
from catenary.maintenance.alerts import (
    RESOLVE_MARGIN_MM,
    announce_alerts,
    evaluate_alerts,
    resolve_alert,
)
from catenary.plugins import AlertRecord, PluginRegistry, hookimpl
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, Run, Track

from .conftest import T0, YEAR, Fleet, alerts_of

LIMIT_30PCT_MM = 8.75  # CTA120 at 30 % loss (reference/wire-profiles.md)


def evaluate(
    session: Session,
    registry: PluginRegistry,
    policy: str = "manufacturer-30pct",
    runs: list[int] | None = None,
    now: datetime | None = None,
    horizon_days: float = 365.0,
) -> Any:
    return evaluate_alerts(
        session,
        registry.limit_policies()[policy],
        registry.wire_types(),
        run_ids=runs,
        now=now or T0 + 10 * YEAR,
        horizon_days=horizon_days,
    )


def test_the_limits_in_the_presets_are_the_reference_figures(registry: PluginRegistry) -> None:
    wire = registry.wire_types()["CTA120"]
    limits = {
        t.rule_number: t.residual_thickness_mm
        for t in thresholds(wire, registry.limit_policies()["china-maintenance-rules"])
    }
    assert limits[1] == pytest.approx(9.26, abs=0.01)  # 25 %
    assert limits[2] == pytest.approx(LIMIT_30PCT_MM, abs=0.01)  # 30 %


def test_a_condition_is_raised_once_whatever_the_order_and_repeats(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        first = fleet.run(track, T0, {3: 9.5})
        second = fleet.run(track, T0 + YEAR, {3: 8.6})
        result = evaluate(session, registry, runs=[second.id])
        assert (len(result.new), result.new_levels["critical"], result.updated) == (1, 1, 0)
        assert result.spans == 10 and result.notes == []
        (alert,) = alerts_of(session)
        assert alert.condition_key == (
            f"threshold/manufacturer-30pct#1/t{track.id}/w0/masts:M03>M04/g0"
        )
        assert (alert.status, alert.value, alert.threshold) == (
            "open",
            8.6,
            pytest.approx(8.75, abs=0.01),
        )
        assert alert.span_measurement.run_id == second.id
        assert alert.details["worn_fraction"] == pytest.approx(0.31, abs=0.01)
        # again, the older run, every span: nothing new, nothing to update
        for runs in ([second.id], [first.id], None):
            again = evaluate(session, registry, runs=runs)
            assert (again.new, again.updated, again.resolved) == ([], 0, 0)
        # a later run lowers the value: the same alert, updated
        third = fleet.run(track, T0 + 2 * YEAR, {3: 8.4})
        later = evaluate(session, registry, runs=[third.id])
        assert (later.new, later.updated) == ([], 1)
        (alert,) = alerts_of(session)
        session.refresh(alert)
        assert alert.value == 8.4 and alert.details["run_id"] == third.id


def test_the_final_state_does_not_depend_on_the_order_runs_are_evaluated(
    engine: Engine, registry: PluginRegistry
) -> None:
    values = [9.4, 8.7, 8.5]

    def build(session: Session, order: list[int]) -> list[tuple[Any, ...]]:
        fleet = Fleet(session)
        track = fleet.track(line=f"L{order[0]}")
        runs = [fleet.run(track, T0 + k * YEAR, {2: v}) for k, v in enumerate(values)]
        for k in order:
            evaluate(session, registry, runs=[runs[k].id])
        return [
            (a.condition_key.split("/", 3)[-1], a.status, a.value)
            for a in alerts_of(session)
            if a.track_id == track.id
        ]

    with session_scope(engine) as session:
        forwards = build(session, [0, 1, 2])
        backwards = build(session, [2, 1, 0])
    assert forwards == backwards == [("w0/masts:M02>M03/g0", "open", 8.5)]


def test_a_run_back_above_the_threshold_resolves_and_a_recurrence_is_a_new_alert(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        fleet.run(track, T0, {5: 8.6})
        evaluate(session, registry)
        # within the margin above the threshold: still open (noise is not a repair)
        fleet.run(track, T0 + YEAR, {5: LIMIT_30PCT_MM + RESOLVE_MARGIN_MM / 2})
        assert evaluate(session, registry).resolved == 0
        replaced = fleet.run(track, T0 + 2 * YEAR, {5: 12.8})  # replaced, not recorded
        result = evaluate(session, registry)
        assert (result.resolved, result.new) == (1, [])
        (alert,) = alerts_of(session)
        session.refresh(alert)
        assert (alert.status, alert.resolved_by_run_id) == ("resolved", replaced.id)
        assert alert.details["resolution"] == "value back above the threshold"
        assert evaluate(session, registry).new == []  # the same runs: nothing raised again
        fleet.run(track, T0 + 3 * YEAR, {5: 8.7})
        recurrence = evaluate(session, registry)
        assert len(recurrence.new) == 1
        assert alerts_of(session)[-1].condition_key.endswith("/w0/masts:M05>M06/g1")


def test_a_repair_resolves_its_alerts_and_restarts_the_history(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        for k in range(4):
            fleet.run(track, T0 + k * YEAR, {3: 10.0 - 0.4 * k, 6: 8.5})
        assert len(evaluate(session, registry).new) == 2  # span 3: a forecast; span 6
        repaired_at = T0 + 3.5 * YEAR
        recorded = record_maintenance(
            session, track, "wire_replaced", 1100.0, 1250.0, repaired_at, "crew 4",
            now=T0 + 4 * YEAR, mast_from="M02", mast_to="M05", actor="test")  # fmt: skip
        resolved = {a.id for a in alerts_of(session) if a.status == "resolved"}
        assert set(recorded.resolved) == resolved
        assert {a.mast_from for a in alerts_of(session) if a.id in resolved} == {"M03"}
        (left,) = [a for a in alerts_of(session) if a.status == "open"]
        assert left.mast_from == "M06"  # beyond the repair
        # the runs before the repair no longer count: no alert, no forecast on span 3
        assert evaluate(session, registry).new == []
        late = fleet.run(track, T0 + 3.2 * YEAR, {3: 8.0, 6: 8.5})  # before the repair
        assert evaluate(session, registry, runs=[late.id]).new == []
        for k in range(3):
            fleet.run(track, repaired_at + (k + 1) * YEAR / 4, {3: 12.9 - 1.0 * k, 6: 8.5})
        result = evaluate(session, registry)
        (forecast,) = [a for a in alerts_of(session) if a.id in result.new]
        assert forecast.kind == "forecast" and forecast.condition_key.endswith("/g1")
        assert forecast.details["runs"] == 3  # the runs after the repair only
        assert forecast.details["wear_rate_mm_per_year"] == pytest.approx(4.0, abs=1e-9)


def test_an_inspection_resolves_nothing(engine: Engine, registry: PluginRegistry) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        fleet.run(track, T0, {3: 8.5})
        evaluate(session, registry)
        recorded = record_maintenance(
            session,
            track,
            "inspected",
            1000.0,
            1500.0,
            T0 + YEAR,
            "inspector",
            now=T0 + YEAR,
            actor="test",
        )
        assert recorded.resolved == () and alerts_of(session)[0].status == "open"


def test_a_point_repair_covers_its_span_only_and_one_wire(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        fleet.run(track, T0, {3: 8.5, 4: 8.5}, overlap={3: 8.4})
        evaluate(session, registry)
        assert len(alerts_of(session)) == 3  # span 3 both wires, span 4
        splice = record_maintenance(
            session,
            track,
            "spliced",
            1162.0,
            1162.5,
            T0 + YEAR,
            "crew",
            now=T0 + YEAR,
            wire=1,
            actor="test",
        )
        (alert,) = [a for a in alerts_of(session) if a.id in splice.resolved]
        assert (alert.mast_from, alert.wire) == ("M03", 1)


def test_resolved_by_hand_is_raised_again_only_from_a_later_run(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        fleet.run(track, T0, {1: 8.5})
        evaluate(session, registry, now=T0 + timedelta(days=10))
        (alert,) = alerts_of(session)
        resolve_alert(
            session,
            alert.id,
            "planner",
            T0 + timedelta(days=20),
            note="measured by hand",
            actor="test",
        )
        assert alert.details["resolved_by"] == "planner"
        assert evaluate(session, registry, now=T0 + timedelta(days=30)).new == []
        fleet.run(track, T0 + timedelta(days=40), {1: 8.5})
        assert len(evaluate(session, registry, now=T0 + timedelta(days=50)).new) == 1


def test_a_forecast_alert_from_the_wear_rate_gives_way_to_the_threshold(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        for k in range(5):  # span 2 wears 0.5 mm/year to 9.0 mm; span 7 0.05 mm/year
            fleet.run(track, T0 + k * YEAR, {2: 11.0 - 0.5 * k, 7: 11.0 - 0.05 * k})
        now = T0 + 4 * YEAR + timedelta(days=30)
        result = evaluate(session, registry, now=now)
        (forecast,) = alerts_of(session)
        assert (forecast.kind, forecast.level, forecast.mast_from) == (
            "forecast",
            "critical",
            "M02",
        )
        assert forecast.details["wear_rate_mm_per_year"] == pytest.approx(0.5, abs=1e-9)
        assert forecast.details["runs"] == 5
        # 9.0 mm at T0 + 4 years, 0.25 mm to go at 0.5 mm/year: about half a year later
        assert forecast.threshold == pytest.approx(LIMIT_30PCT_MM, abs=0.005)
        due = T0 + (4.0 + (9.0 - forecast.threshold) / 0.5) * YEAR
        assert forecast.details["reach_at"] == due.isoformat(timespec="seconds")
        assert forecast.details["reach_earliest"] == forecast.details["reach_latest"]
        assert result.new_levels == {"critical": 1}
        assert evaluate(session, registry, now=now).updated == 0
        fleet.run(track, T0 + 5 * YEAR, {2: 8.5})
        result = evaluate(session, registry, now=T0 + 5 * YEAR + timedelta(days=1))
        assert (len(result.new), result.resolved) == (1, 1)
        session.refresh(forecast)
        assert forecast.status == "resolved"
        assert forecast.details["resolution"].startswith("threshold met")
        assert alerts_of(session)[-1].kind == "threshold"


def test_a_forecast_beyond_the_horizon_is_not_raised_or_is_resolved(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        for k in range(4):  # reaches 8.75 mm at T0 + 4.5 years
            fleet.run(track, T0 + k * YEAR, {2: 11.0 - 0.5 * k})
        now = T0 + 3 * YEAR + timedelta(days=30)
        assert evaluate(session, registry, now=now, horizon_days=365).new == []
        assert len(evaluate(session, registry, now=now, horizon_days=600).new) == 1
        result = evaluate(session, registry, now=now, horizon_days=365)
        assert result.resolved == 1
        (forecast,) = alerts_of(session)
        session.refresh(forecast)
        assert forecast.details["resolution"] == "forecast beyond the planning horizon"


def test_wires_are_told_apart_by_position_whatever_the_run_numbers(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        # the right wire of the overlap in span 4 is worn; the other direction numbers it 0
        up = fleet.run(track, T0, overlap={4: 8.6}, direction="increasing")
        down = fleet.run(track, T0 + YEAR, overlap={4: 8.5}, direction="decreasing")
        assert {m.wire for m in down.span_measurements if m.span == 4} == {0, 1}
        result = evaluate(session, registry)
        assert len(result.new) == 1 and result.spans == 11  # 10 spans, 2 wires in one
        (alert,) = alerts_of(session)
        assert (alert.wire, alert.value, alert.details["run_wire"]) == (1, 8.5, 0)
        worn = [m for m in up.span_measurements if m.span == 4 and m.min_residual_thickness_mm < 9]
        assert worn[0].wire == 1


def test_anchor_section_average(engine: Engine, registry: PluginRegistry) -> None:
    sections = ["A"] * 5 + ["B"] * 6  # spans 0-4 in A (M00 to M05), 5-9 in B
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track(sections=sections)
        plain = fleet.track(track="2")  # no anchor sections
        mean = {k: 9.1 for k in range(5)}  # section A: 9.1 mm on average, below 9.26 mm
        fleet.run(track, T0, mean_mm=mean)
        fleet.run(plain, T0, mean_mm=mean)
        fleet.run(track, T0 + YEAR, mean_mm={0: 12.0, 1: 12.0}, spans=[0, 1, 5])  # A in part
        result = evaluate(session, registry, policy="china-maintenance-rules")
        assert result.sections == 2 and result.notes == []
        (alert,) = alerts_of(session)
        assert (alert.level, alert.kind, alert.wire) == ("plan", "threshold", 0)
        assert (alert.mast_from, alert.mast_to) == ("M00", "M05")
        assert (alert.start_chainage_m, alert.end_chainage_m) == (1000.0, 1250.0)
        assert alert.value == pytest.approx(9.1) and alert.details["anchor_section"] == "A"
        assert alert.condition_key.endswith("/w0/section:A/g0")
        assert alert.details["coverage"] == 1.0  # the partial run does not count
        # without anchor sections the rule is evaluated on nothing, and the result says so once
        no_sections = _evaluate_track(session, registry, plain)
        assert no_sections.new == [] and no_sections.sections == 0
        assert len(no_sections.notes) == 1 and "evaluated on nothing" in no_sections.notes[0]
        # replacing the section resolves it; replacing a part of it does not
        part = record_maintenance(session, track, "wire_replaced", 1000.0, 1100.0, T0 + 2 * YEAR,
                                  "crew", now=T0 + 2 * YEAR, actor="test")  # fmt: skip
        assert part.resolved == ()
        whole = record_maintenance(session, track, "wire_replaced", 1000.0, 1250.0, T0 + 2 * YEAR,
                                   "crew", now=T0 + 2 * YEAR, actor="test")  # fmt: skip
        assert whole.resolved == (alert.id,)


def _evaluate_track(session: Session, registry: PluginRegistry, track: Track) -> Any:
    runs = list(session.scalars(select(Run.id).where(Run.track_id == track.id)))
    return evaluate(session, registry, policy="china-maintenance-rules", runs=runs)


def test_evaluating_a_run_looks_at_its_spans_only(engine: Engine, registry: PluginRegistry) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track, other = fleet.track(), fleet.track(line="L2")
        fleet.run(track, T0, {7: 8.5})
        fleet.run(other, T0, {7: 8.5})
        part = fleet.run(track, T0 + YEAR, spans=[0, 1, 2, 3])
        result = evaluate(session, registry, runs=[part.id])
        assert (result.spans, result.new) == (4, [])
        assert len(evaluate(session, registry).new) == 2


def test_new_alerts_are_announced_with_their_fields(
    engine: Engine, registry: PluginRegistry
) -> None:
    received: list[AlertRecord] = []

    class Probe:
        @hookimpl
        def catenary_alert_raised(self, alert: AlertRecord) -> None:
            received.append(alert)

    with session_scope(engine) as session:
        fleet = Fleet(session)
        fleet.run(fleet.track(), T0, {3: 8.5, 4: 8.6})
        new = evaluate(session, registry).new
    probe = PluginRegistry(autoload=False, plugins=[("probe", Probe())])
    announce_alerts(engine, probe, new)
    assert [r.id for r in received] == new
    assert received[0].line == "L1" and received[0].track == "1"
    assert received[0].condition_key.startswith("threshold/")
    with session_scope(engine) as session:
        stored = session.get(Alert, new[0])
        assert stored is not None and AlertRecord.of(stored).value == 8.5
    assert received[0].as_json()["raised_at"] == received[0].raised_at  # ISO 8601 text
    with pytest.warns(DeprecationWarning, match=r"AlertRecord\['line'\] is deprecated"):
        assert received[0]["line"] == "L1"  # as plugins written for catenary 0.1 read it
    assert received[0].get("no such field", "-") == "-"


def test_spans_of_an_unknown_wire_type_are_said_and_left_alone(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        fleet.run(track, T0, {3: 6.0}, wire_type="XW-95")
        result = evaluate(session, registry)
        assert result.new == [] and result.spans == 10
        assert result.notes == [
            "span measurements of a wire type no plugin registers are not evaluated"
        ]


def test_a_track_without_masts_is_evaluated_by_chainage(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        bare = fleet.track(line="L2", masts=0)
        run = fleet.run(bare, T0, {3: 8.5})  # spans cut without a register: no mast named
        result = evaluate(session, registry, runs=[run.id])
        assert result.spans == 10
        (alert,) = (session.get(Alert, k) for k in result.new)
        assert alert is not None and alert.track_id == bare.id and alert.value == 8.5


def test_the_fleet_is_evaluated_with_a_track_without_masts_beside_others(
    engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track, bare = fleet.track(), fleet.track(line="L2", masts=0)
        fleet.run(track, T0, {7: 8.5})
        fleet.run(bare, T0, {3: 8.6})
        result = evaluate(session, registry)  # the whole fleet
        assert result.spans == 20
        tracks = {(a.track_id, a.value) for a in alerts_of(session)}
        assert tracks == {(track.id, 8.5), (bare.id, 8.6)}
