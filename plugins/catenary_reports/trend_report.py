"""The fleet trend report: the worst wear rates, and the spans forecast to reach a limit within
the planning horizon.

For one line (``--line``, optionally ``--track``) or every line, each track's histories (a
span and wire position across runs, from its last repair on) are fitted and the local rules
of the policy forecast on them as the alerts do (``catenary.maintenance.trends``):

- **worst wear rates**: the ``top`` histories (option, default 20) by wear rate [mm/year],
  with the rate's 95 % interval; only histories of at least ``MIN_RUNS`` runs have a rate;
- **due within the horizon**: every history and rule whose fitted line reaches the rule's
  threshold by the end of the horizon (``[maintenance] horizon_days``, the alerts' horizon),
  earliest first; a date before today is a limit already reached by the line.

``.html`` holds both; ``.csv``/``.parquet`` one row per history of either list, worst rate
first, with its earliest limit due within the horizon (empty when none).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pyarrow as pa
from sqlalchemy import select
from sqlalchemy.orm import Session

from catenary.errors import UserError
from catenary.maintenance.alerts import horizon_days
from catenary.maintenance.forecast import (
    CONFIDENCE,
    MIN_RUNS,
    reach_text,
    years_since_epoch,
)
from catenary.maintenance.trends import TrackTrends, rate_interval, track_trends
from catenary.measurement.samples import TABLE_SUFFIXES, export_table
from catenary.plugins import ReportRequest
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import Line, Track
from catenary_reports import html
from catenary_reports.html import Cell, number
from catenary_reports.request import Option, check_output, parse_request

__all__ = ["OPTIONS", "track_of", "tracks_of", "write"]

OPTIONS = {"top": Option(20.0, 1.0, 10_000.0, "rows")}
"""``--set top=N``: how many of the worst wear rates are listed."""

_DAYS_PER_YEAR = 365.25


def tracks_of(session: Session, line: str | None, track: str | None) -> list[tuple[int, str, str]]:
    """The tracks of ``line`` (only ``track``; None: every line) as (id, line code, track
    code), by codes; an unknown line or track is a ``UserError`` naming the known ones."""
    lines = list(session.execute(select(Line.id, Line.code).order_by(Line.code)))
    if line is not None:
        chosen = [x for x in lines if x.code == line]
        if not chosen:
            known = ", ".join(x.code for x in lines) or "none"
            raise UserError(f"no line {line!r} in the database (known: {known})")
        lines = chosen
    out: list[tuple[int, str, str]] = []
    for line_id, code in lines:
        tracks = list(
            session.execute(
                select(Track.id, Track.code).where(Track.line_id == line_id).order_by(Track.code)
            )
        )
        if track is not None:
            found = [t for t in tracks if t.code == track]
            if not found:
                known = ", ".join(t.code for t in tracks) or "none"
                raise UserError(f"line {line!r} has no track {track!r} (known: {known})")
            tracks = found
        out += [(int(t.id), code, t.code) for t in tracks]
    return out


def track_of(session: Session, line: str, track: str) -> int:
    """The id of track ``track`` of line ``line`` (a ``UserError`` naming the known ones)."""
    return tracks_of(session, line, track)[0][0]


@dataclass(frozen=True)
class _Entry:
    """A listed history: its rank by wear rate in the fleet (1: the fastest), its rate and
    interval [mm/year], and its earliest limit due within the horizon (an index into the
    track's ``limits``, -1: none)."""

    line: str
    track: str
    trends: TrackTrends
    h: int
    rank: int
    rate: float
    low: float
    high: float
    due: int

    @property
    def masts(self) -> tuple[str | None, str | None]:
        hist, codes = self.trends.histories, self.trends.data.mast_code
        if hist.mast_from[self.h] < 0:
            return None, None
        return codes[hist.mast_from[self.h]], codes[hist.mast_to[self.h]]

    def reach(self, which: str) -> str | None:
        """The due limit's reach date (``central``, ``low``, ``high``) as ISO, or None."""
        if self.due < 0:
            return None
        return reach_text(float(getattr(self.trends.limits[self.due].reach, which)[self.h]))


@dataclass(frozen=True)
class _Listed:
    """What the report lists: the histories among the ``top`` worst wear rates or with a limit
    due (by rank), every (history, limit) due (earliest first), and how many have a rate."""

    entries: list[_Entry]
    due: list[tuple[_Entry, int]]
    rated: int


def _listed(tracks: list[tuple[str, str, TrackTrends]], horizon_end: float, top: int) -> _Listed:
    """Rank every history with a rate (vectorised over the fleet's histories) and keep those
    the report lists; Python works per listed history only."""
    owner, history, rates, due_first = [], [], [], []
    for index, (_, _, trends) in enumerate(tracks):
        hist = trends.histories
        rated = (hist.latest >= 0) & (hist.fit.runs >= MIN_RUNS)
        rated &= np.isfinite(hist.fit.slope_mm_per_year)
        found = np.flatnonzero(rated)
        central = np.array([limit.reach.central[found] for limit in trends.limits]).reshape(
            len(trends.limits), found.shape[0]
        )
        within = np.where(central <= horizon_end, central, np.inf)
        first = np.argmin(within, axis=0) if trends.limits else np.zeros(found.shape[0], int)
        due = np.isfinite(within.min(axis=0, initial=np.inf))
        owner.append(np.full(found.shape[0], index))
        history.append(found)
        rates.append(hist.fit.wear_rate_mm_per_year[found])
        due_first.append(np.where(due, first, -1))
    rate = np.concatenate([np.zeros(0), *rates])
    order = np.argsort(-rate, kind="stable")
    rank = np.empty(order.shape[0], dtype=np.int64)
    rank[order] = np.arange(1, order.shape[0] + 1)
    owners = np.concatenate([np.zeros(0, int), *owner])
    histories = np.concatenate([np.zeros(0, int), *history])
    first_due = np.concatenate([np.zeros(0, int), *due_first])
    entries: list[_Entry] = []
    due_pairs: list[tuple[_Entry, int]] = []
    for k in order[(rank[order] <= top) | (first_due[order] >= 0)].tolist():
        line, code, trends = tracks[int(owners[k])]
        h = int(histories[k])
        low, high = rate_interval(trends.histories.fit.take(np.array([h])))
        entry = _Entry(
            line,
            code,
            trends,
            h,
            int(rank[k]),
            float(rate[k]) + 0.0,  # + 0.0: no "-0" for a wire that does not wear
            float(low[0]) + 0.0,
            float(high[0]) + 0.0,
            int(first_due[k]),
        )
        entries.append(entry)
        due_pairs += [
            (entry, j)
            for j, limit in enumerate(trends.limits)
            if float(limit.reach.central[h]) <= horizon_end and np.isfinite(limit.reach.central[h])
        ]
    due_pairs.sort(key=lambda p: float(p[0].trends.limits[p[1]].reach.central[p[0].h]))
    return _Listed(entries, due_pairs, int(rate.shape[0]))


_MM = {"unit": "mm"}
"""A wear rate's figures are millimetres (per year): in CSV to 0.001 mm, as every length."""

_SCHEMA = pa.schema(
    [
        ("line", pa.string()),
        ("track", pa.string()),
        ("mast_from", pa.string()),
        ("mast_to", pa.string()),
        ("from_m", pa.float64()),
        ("to_m", pa.float64()),
        ("wire_position", pa.int64()),
        ("wire_type", pa.string()),
        ("runs", pa.int64()),
        ("latest_min_mm", pa.float64()),
        pa.field("wear_rate_mm_per_year", pa.float64(), metadata=_MM),
        pa.field("wear_rate_low_mm_per_year", pa.float64(), metadata=_MM),
        pa.field("wear_rate_high_mm_per_year", pa.float64(), metadata=_MM),
        ("rank", pa.int64()),
        ("limit_level", pa.string()),
        ("limit_mm", pa.float64()),
        ("reach_date", pa.string()),
        ("reach_earliest", pa.string()),
        ("reach_latest", pa.string()),
    ]
)


def _wire_type(e: _Entry) -> str:
    kind = int(e.trends.wire_type[e.h])
    return e.trends.wire_type_names[kind] if kind >= 0 else ""


def _latest_min(e: _Entry) -> float:
    rows = e.trends.data.rows
    return float(rows.min_thickness_mm[e.trends.histories.latest[e.h]])


def _table(entries: list[_Entry]) -> pa.Table:
    rows = []
    for e in entries:
        hist = e.trends.histories
        mast_from, mast_to = e.masts
        limit = e.trends.limits[e.due] if e.due >= 0 else None
        rows.append(
            {
                "line": e.line,
                "track": e.track,
                "mast_from": mast_from,
                "mast_to": mast_to,
                "from_m": float(hist.start_m[e.h]),
                "to_m": float(hist.end_m[e.h]),
                "wire_position": int(hist.position[e.h]),
                "wire_type": _wire_type(e),
                "runs": int(hist.fit.runs[e.h]),
                "latest_min_mm": _latest_min(e),
                "wear_rate_mm_per_year": e.rate,
                "wear_rate_low_mm_per_year": e.low,
                "wear_rate_high_mm_per_year": e.high,
                "rank": e.rank,
                "limit_level": limit.rule.rule.level if limit else None,
                "limit_mm": float(limit.threshold_mm[e.h]) if limit else None,
                "reach_date": e.reach("central"),
                "reach_earliest": e.reach("low"),
                "reach_latest": e.reach("high"),
            }
        )
    return pa.Table.from_pylist(rows, schema=_SCHEMA)


def _place(e: _Entry) -> list[Cell | str]:
    hist = e.trends.histories
    mast_from, mast_to = e.masts
    return [
        Cell(f"{e.line} track {e.track}", keep=True),
        Cell(f"{mast_from} to {mast_to}" if mast_from else "", keep=True),
        number(float(hist.start_m[e.h]), 1),
        number(float(hist.end_m[e.h]), 1),
        Cell(str(hist.position[e.h]), numeric=True),
        _wire_type(e),
    ]


_PLACE = ["line, track", "masts", "from m", "to m", "wire position", "wire type"]


def _html(listed: _Listed, top: int, facts: list[tuple[str, str]]) -> str:
    now = datetime.now(UTC)
    worst = [e for e in listed.entries if e.rank <= top]
    rates = [
        [
            Cell(str(e.rank), numeric=True),
            *_place(e),
            Cell(str(int(e.trends.histories.fit.runs[e.h])), numeric=True),
            number(_latest_min(e)),
            number(e.rate, 3),
            Cell(f"{e.low:.3f} to {e.high:.3f}", keep=True),
        ]
        for e in worst
    ]
    due_rows = []
    for e, k in listed.due:
        limit = e.trends.limits[k]
        reach = limit.reach
        due_rows.append(
            [
                Cell(reach_text(float(reach.central[e.h])), keep=True),
                Cell(
                    f"{reach_text(float(reach.low[e.h]))} to {reach_text(float(reach.high[e.h]))}",
                    keep=True,
                ),
                Cell(markup=html.tag(limit.rule.rule.level)),
                number(float(limit.threshold_mm[e.h])),
                *_place(e),
                number(_latest_min(e)),
                number(e.rate, 3),
                limit.rule.name,
            ]
        )
    parts = [
        html.section(
            "Summary", html.facts([*facts, ("Generated", html.stamp(now))]), section_id="summary"
        ),
        html.section(
            "Worst wear rates",
            html.note(
                f"Span-wires by wear rate (least squares over the runs since the last repair, "
                f"at least {MIN_RUNS}), with its {CONFIDENCE:.0%} interval."
            ),
            html.table(
                ["rank", *_PLACE, "runs", "latest min mm", "wear mm/year", "interval mm/year"],
                rates,
                table_id="rates",
                empty="No span-wire has a wear rate yet.",
            ),
            section_id="rates-section",
        ),
        html.section(
            "Due within the horizon",
            html.note(
                "Each span-wire and rule whose fitted line reaches the rule's threshold by the "
                "end of the planning horizon, earliest first (the interval is the date's "
                f"{CONFIDENCE:.0%} interval; a date in the past: already reached by the line)."
            ),
            html.table(
                [
                    "date",
                    "interval",
                    "level",
                    "limit mm",
                    *_PLACE,
                    "latest min mm",
                    "wear mm/year",
                    "rule",
                ],
                due_rows,
                row_classes=[e.trends.limits[k].rule.rule.level for e, k in listed.due],
                table_id="due",
                empty="Nothing is forecast to reach a limit within the horizon.",
            ),
            section_id="due-section",
        ),
    ]
    return html.page("Wear trends", f"generated {html.stamp(now)}", parts)


def write(raw: ReportRequest, output: Path) -> Path:
    """Write the trend report of ``raw['line']`` (every line when None) to ``output``."""
    request = parse_request("trends", raw, line=True, options=OPTIONS)
    suffix = check_output(output, (".html", *TABLE_SUFFIXES))
    top = int(request.options["top"])
    horizon = horizon_days(request.settings)
    now = datetime.now(UTC)
    horizon_end = float(years_since_epoch([now])[0]) + horizon / _DAYS_PER_YEAR
    wire_types = request.registry.wire_types()
    with (
        open_database(request.settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        tracks = [
            (line, code, track_trends(session, track_id, wire_types, request.policy))
            for track_id, line, code in tracks_of(session, request.line, request.track)
        ]
    listed = _listed(tracks, horizon_end, top)
    if suffix != ".html":
        export_table(iter([_table(listed.entries)]), _SCHEMA, output)
        return output
    if request.line is None:
        where = "every line"
    else:
        where = f"line {request.line}" + (f" track {request.track}" if request.track else "")
    policy = request.policy
    facts = [
        ("Lines and tracks", f"{where} ({len(tracks)} track(s))"),
        (
            "Wear-limit policy",
            f"{policy.name}: {policy.description}" if policy else "none configured: no forecast",
        ),
        ("Horizon", f"{horizon:g} days, to {(now + timedelta(days=horizon)).date().isoformat()}"),
        ("Span-wires with a wear rate", str(listed.rated)),
        ("Due within the horizon", f"{sum(e.due >= 0 for e in listed.entries)} span-wires"),
    ]
    return html.write_text(output, _html(listed, top, facts))
