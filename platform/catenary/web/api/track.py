"""The API's track: ``GET /tracks/profile``, a track along its chainage for the track view.

A window of chainage of the track's latest run (or a given one) and of the run before it, per
wire position: the minimum and maximum of residual thickness, height and stagger per bin of
the coarsest envelope level that fills ``columns`` pixel columns, or the samples themselves
below about a kilometre (``catenary.measurement.envelope.track_view``); with the wear and
geometry limits, the masts (design stagger and height) and the active alerts of the window.
Arrays, not an object per point; NaN is null.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import datetime
from typing import Annotated

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from pydantic import BaseModel
from sqlalchemy import and_, func, or_, select
from sqlalchemy.orm import Session

from catenary.arrays import FloatArray, IntArray
from catenary.errors import UserError
from catenary.limits import LEVELS, LimitPolicy, choose_policy, thresholds
from catenary.measurement.envelope import (
    QUANTITIES,
    Bins,
    TrackView,
    choose_level,
    merge_bins,
    track_view,
)
from catenary.positions import positions_along
from catenary.storage.columns import fetch_columns
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, Mast, Run, SpanMeasurement, Track
from catenary.storage.store import Store
from catenary.web.api.runs import run_of, track_of
from catenary.web.app import WebState, state
from catenary.web.auth import Principal, requires
from catenary.web.errors import NotFound

__all__ = ["TrackProfileOut", "router", "track_extent", "track_of", "track_runs"]

router = APIRouter(tags=["track"])

ACTIVE = ("open", "acknowledged")
"""The alerts the track view shows."""
DECIMALS = 3
"""Numbers are sent to 0.001 mm and 0.001 m (what they mean: FORMATS.md)."""
FIELDS = {
    "residual_thickness_mm": ("min_residual_thickness_mm", "max_residual_thickness_mm"),
    "height_mm": ("height_min_mm", "height_max_mm"),
    "stagger_mm": ("stagger_min_mm", "stagger_max_mm"),
}
"""Each quantity's minimum and maximum as named in the JSON (the ``spans`` export's names)."""
assert set(FIELDS) == set(QUANTITIES)

Numbers = list[float | None]


class WireProfileOut(BaseModel):
    """One wire position of a run along the window, by increasing chainage: per point the
    bin's start (``chainage_m``; the bin covers ``[chainage_m, chainage_m + bin_m)``) and
    the minimum and maximum of each quantity in it; raw samples: each sample's chainage and
    values in the ``min`` arrays, the ``max`` arrays null."""

    wire_position: int
    chainage_m: list[float]
    min_residual_thickness_mm: Numbers
    max_residual_thickness_mm: Numbers | None
    height_min_mm: Numbers
    height_max_mm: Numbers | None
    stagger_min_mm: Numbers
    stagger_max_mm: Numbers | None


class RunProfileOut(BaseModel):
    """A run of the track and its wire positions along the window; ``problem`` says why it
    has none where its samples cannot be read."""

    id: int
    uuid: str
    started_at: datetime
    direction: str
    vehicle: str
    processing_uuid: str | None
    wires: list[WireProfileOut]
    problem: str | None = None


class WearLimitOut(BaseModel):
    """A wear rule of the policy for a wire type of the window, as residual thickness."""

    wire_type: str
    level: str
    scope: str
    residual_thickness_mm: float
    worn_fraction: float
    criterion: str


class GeometryLimitOut(BaseModel):
    """A height or stagger rule of the policy (null: a limit it does not give)."""

    check: str
    level: str
    min_mm: float | None
    max_mm: float | None
    max_abs_mm: float | None
    min_speed_kmh: float | None
    max_speed_kmh: float | None
    criterion: str


class LimitsOut(BaseModel):
    """The limit policy's rules for the window: ``policy`` its name (null: none configured
    and no wire type known); ``unknown_wire_types``, the window's wire types no plugin
    provides (no wear limit for them)."""

    policy: str | None
    wear: list[WearLimitOut]
    geometry: list[GeometryLimitOut]
    unknown_wire_types: list[str]


class MastsOut(BaseModel):
    """The masts of the window and the nearest either side of it, by chainage."""

    mast: list[str]
    chainage_m: list[float]
    wire_type: list[str]
    design_stagger_mm: Numbers
    design_height_mm: Numbers


class AlertsOut(BaseModel):
    """The active alerts (open, acknowledged) that meet the window, by start chainage."""

    id: list[int]
    level: list[str]
    kind: list[str]
    status: list[str]
    rule: list[str]
    wire_position: list[int]
    mast_from: list[str | None]
    mast_to: list[str | None]
    start_chainage_m: list[float]
    end_chainage_m: list[float]
    value: Numbers
    threshold: Numbers


class TrackProfileOut(BaseModel):
    """A track along window ``[from_m, to_m]`` drawn on ``columns`` pixel columns, read at
    envelope level ``level_m`` (null: the raw samples; ``resolution`` says which as text),
    its bins gathered ``bin_m`` wide (a whole number of them, about a pixel column or less);
    ``extent_m``, the chainage the track's masts and latest run cover (null: nothing)."""

    line: str
    track: str
    from_m: float
    to_m: float
    columns: int
    level_m: float | None
    bin_m: float | None
    resolution: str
    extent_m: list[float] | None
    latest: RunProfileOut | None
    previous: RunProfileOut | None
    limits: LimitsOut
    masts: MastsOut
    alerts: AlertsOut


def track_runs(
    session: Session, track: Track, reference: str | None = None
) -> tuple[Run | None, Run | None]:
    """The run to show (``reference``, else the track's latest complete run) and the
    track's complete run started before it, by start time."""
    stored = select(Run).where(
        Run.track_id == track.id, Run.processing_id.is_not(None), Run.status == "complete"
    )
    latest_first = (Run.started_at.desc(), Run.id.desc())
    if reference is None:
        run = session.scalars(stored.order_by(*latest_first).limit(1)).first()
        if run is None:
            return None, None
    else:
        run = run_of(session, reference)
        if run.track_id != track.id:
            raise NotFound(
                f"run {reference} is not on line {track.line.code!r} track {track.code!r}"
            )
    earlier = or_(
        Run.started_at < run.started_at, and_(Run.started_at == run.started_at, Run.id < run.id)
    )
    previous = session.scalars(stored.where(earlier).order_by(*latest_first).limit(1)).first()
    return run, previous


def track_extent(session: Session, track: Track, run: Run | None) -> tuple[float, float] | None:
    """The chainage ``track``'s masts and ``run``'s spans cover, None if nothing."""
    low, high = session.execute(
        select(func.min(Mast.chainage_m), func.max(Mast.chainage_m)).where(
            Mast.track_id == track.id
        )
    ).one()
    ends = [v for v in (low, high) if v is not None]
    if run is not None and run.processing_id is not None:
        ends += [
            v
            for v in session.execute(
                select(
                    func.min(SpanMeasurement.start_chainage_m),
                    func.max(SpanMeasurement.end_chainage_m),
                ).where(SpanMeasurement.processing_id == run.processing_id)
            ).one()
            if v is not None
        ]
    if not ends or min(ends) >= max(ends):
        return None
    return float(min(ends)), float(max(ends))


def _numbers(values: FloatArray) -> Numbers:
    """``values`` to ``DECIMALS``, NaN as None."""
    rounded = np.round(values, DECIMALS)
    return [None if v != v else v for v in rounded.tolist()]


def _by_position(view: TrackView, spans: FloatArray, factor: int) -> list[WireProfileOut]:
    """The view's traces (per wire of the run) per wire position: ``spans``, shape (m, 3),
    gives each span measurement's wire, wire position and start chainage [m]. A bin is
    placed by its centre; two wires' bins of one position and chainage are gathered into one,
    and ``factor`` bins into one; points of a wire without a span measurement are left
    out."""
    traces = list(view.wires.items())
    if not traces:
        return []
    chainage = np.concatenate([t.chainage_m for _, t in traces])
    wire = np.concatenate([np.full(t.chainage_m.shape, n, dtype=np.int64) for n, t in traces])
    low = {q: np.concatenate([t.low[q] for _, t in traces]) for q in FIELDS}
    high = {q: np.concatenate([t.high[q] for _, t in traces]) for q in FIELDS}
    centre = chainage + (view.level_m or 0.0) / 2.0
    position = positions_along(
        centre,
        wire,
        spans[:, 2],
        spans[:, 0].astype(np.int64),
        spans[:, 1].astype(np.int64),
    )
    known = position >= 0
    if view.level_m is None:
        order = np.lexsort((chainage[known], position[known]))
        return _wires(
            position[known][order],
            chainage[known][order],
            {q: v[known][order] for q, v in low.items()},
            None,
        )
    bins = merge_bins(
        [
            Bins(
                view.level_m,
                position[known],
                np.round(chainage[known] / view.level_m).astype(np.int64),
                np.ones(int(known.sum()), dtype=np.int64),
                {q: v[known] for q, v in low.items()},
                {q: v[known] for q, v in high.items()},
            )
        ],
        factor,
    )
    return _wires(bins.wire, bins.chainage_m, bins.low, bins.high)


def _wires(
    position: IntArray,
    chainage_m: FloatArray,
    low: Mapping[str, FloatArray],
    high: Mapping[str, FloatArray] | None,
) -> list[WireProfileOut]:
    """Rows sorted by position then chainage, one ``WireProfileOut`` per position."""
    numbers, first = np.unique(position, return_index=True)
    bounds = [*first.tolist(), position.shape[0]]
    found = []
    for number, begin, end in zip(numbers.tolist(), bounds[:-1], bounds[1:], strict=True):
        values: dict[str, Numbers | None] = {}
        for quantity, (low_name, high_name) in FIELDS.items():
            values[low_name] = _numbers(low[quantity][begin:end])
            values[high_name] = None if high is None else _numbers(high[quantity][begin:end])
        found.append(
            WireProfileOut(
                wire_position=int(number),
                chainage_m=np.round(chainage_m[begin:end], DECIMALS).tolist(),
                **values,  # type: ignore[arg-type]
            )
        )
    return found


def _run_profile(
    session: Session, store: Store, run: Run, from_m: float, to_m: float, columns: int
) -> RunProfileOut:
    """``run`` along the window, its bins gathered as ``gathered`` says."""
    processing = run.processing
    wires: list[WireProfileOut] = []
    problem = None
    if processing is None or processing.samples_key is None:
        problem = f"run {run.id} has no samples file"
    else:
        try:
            view = track_view(store, processing.samples_key, from_m, to_m, columns, QUANTITIES)
        except UserError as exc:  # a store that lacks the file or cannot be reached
            problem = str(exc)
        else:
            spans = fetch_columns(
                session.connection(),
                select(
                    SpanMeasurement.wire,
                    SpanMeasurement.wire_position,
                    SpanMeasurement.start_chainage_m,
                ).where(
                    SpanMeasurement.processing_id == processing.id,
                    SpanMeasurement.start_chainage_m <= to_m + (view.level_m or 0.0),
                    SpanMeasurement.end_chainage_m >= from_m - (view.level_m or 0.0),
                ),
            )
            wires = _by_position(
                view,
                np.column_stack(
                    [spans["wire"], spans["wire_position"], spans["start_chainage_m"]]
                ).astype(np.float64),
                gathered(view.level_m, from_m, to_m, columns),
            )
    return RunProfileOut(
        id=run.id,
        uuid=run.uuid,
        started_at=run.started_at,
        direction=run.direction,
        vehicle=run.vehicle.name,
        processing_uuid=processing.uuid if processing else None,
        wires=wires,
        problem=problem,
    )


def _masts(session: Session, track: Track, from_m: float, to_m: float) -> list[Mast]:
    """The masts of ``[from_m, to_m]`` and the nearest either side, by chainage."""
    on_track = select(Mast).where(Mast.track_id == track.id)
    before = session.scalars(
        on_track.where(Mast.chainage_m < from_m).order_by(Mast.chainage_m.desc()).limit(1)
    ).all()
    inside = session.scalars(
        on_track.where(Mast.chainage_m >= from_m, Mast.chainage_m <= to_m).order_by(Mast.chainage_m)
    ).all()
    after = session.scalars(
        on_track.where(Mast.chainage_m > to_m).order_by(Mast.chainage_m).limit(1)
    ).all()
    return [*before, *inside, *after]


def _alerts(session: Session, track: Track, from_m: float, to_m: float) -> AlertsOut:
    alerts = session.scalars(
        select(Alert)
        .where(
            Alert.track_id == track.id,
            Alert.status.in_(ACTIVE),
            Alert.start_chainage_m <= to_m,
            Alert.end_chainage_m >= from_m,
        )
        .order_by(Alert.start_chainage_m, Alert.id)
    ).all()
    return AlertsOut(
        id=[a.id for a in alerts],
        level=[a.level for a in alerts],
        kind=[a.kind for a in alerts],
        status=[a.status for a in alerts],
        rule=[a.rule for a in alerts],
        wire_position=[a.wire for a in alerts],
        mast_from=[a.mast_from for a in alerts],
        mast_to=[a.mast_to for a in alerts],
        start_chainage_m=[a.start_chainage_m for a in alerts],
        end_chainage_m=[a.end_chainage_m for a in alerts],
        value=_numbers(np.array([a.value for a in alerts], dtype=np.float64)),
        threshold=_numbers(np.array([a.threshold for a in alerts], dtype=np.float64)),
    )


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _limits(web: WebState, wire_types: set[str]) -> LimitsOut:
    """The policy's wear rules for ``wire_types`` and its height and stagger rules: the
    configured policy, else the wire types' standard limits (as the alerts and reports)."""
    known = web.registry.wire_types()
    policy: LimitPolicy | None = choose_policy(
        web.settings, web.registry.limit_policies(), wire_types=known
    )
    wear = []
    geometry = []
    if policy is not None:
        for name in sorted(wire_types & set(known)):
            wear += [
                WearLimitOut(
                    wire_type=name,
                    level=t.level,
                    scope=t.scope,
                    residual_thickness_mm=round(t.residual_thickness_mm, DECIMALS),
                    worn_fraction=round(t.worn_fraction, 4),
                    criterion=t.rule.criterion,
                )
                for t in thresholds(known[name], policy)
            ]
        geometry = [
            GeometryLimitOut(
                check=rule.check,
                level=rule.level,
                min_mm=_finite(rule.min_mm),
                max_mm=_finite(rule.max_mm),
                max_abs_mm=_finite(rule.max_abs_mm),
                min_speed_kmh=_finite(rule.min_speed_kmh),
                max_speed_kmh=_finite(rule.max_speed_kmh),
                criterion=rule.criterion,
            )
            for rule in policy.geometry
            if rule.check in ("height", "stagger")
        ]
    wear.sort(key=lambda w: (w.wire_type, LEVELS.index(w.level)))
    return LimitsOut(
        policy=policy.name if policy else None,
        wear=wear,
        geometry=geometry,
        unknown_wire_types=sorted(wire_types - set(known)),
    )


def gathered(level_m: float | None, from_m: float, to_m: float, columns: int) -> int:
    """How many bins of level ``level_m`` are sent as one: as many as a pixel column of window
    ``[from_m, to_m]`` holds (the picture is the same, the answer smaller), at least one."""
    if level_m is None:
        return 1
    return max(1, math.floor((to_m - from_m) / columns / level_m))


def resolution(level_m: float | None) -> str:
    """A level as people read it: ``raw`` or its bin width (``10 m``)."""
    return "raw" if level_m is None else f"{level_m:g} m"


@router.get("/tracks/profile")
def track_profile(
    request: Request,
    user: Annotated[Principal, requires("viewer")],
    line: Annotated[str, Query(max_length=64, description="The line's code.")],
    track: Annotated[str, Query(max_length=64, description="The track's code.")],
    from_m: Annotated[
        float | None,
        Query(allow_inf_nan=False, description="Window start [m]; default the track's start."),
    ] = None,
    to_m: Annotated[
        float | None,
        Query(allow_inf_nan=False, description="Window end [m]; default the track's end."),
    ] = None,
    columns: Annotated[
        int, Query(ge=100, le=4000, description="The plot's width in pixel columns.")
    ] = 1200,
    run: Annotated[
        str | None,
        Query(
            max_length=64,
            description="The run to show (id, UUID, prefix of it); default the track's latest.",
        ),
    ] = None,
) -> TrackProfileOut:
    """A track along a window of chainage: the run's and the previous run's residual
    thickness, height and stagger per wire position (min/max per envelope bin, or the raw
    samples below about 1 km), the limits, masts and active alerts."""
    web = state(request)
    with session_scope(web.engine, read_only=True) as session:
        found = track_of(session, line, track)
        shown, previous = track_runs(session, found, run)
        extent = track_extent(session, found, shown)
        start = from_m if from_m is not None else (extent[0] if extent else 0.0)
        end = to_m if to_m is not None else (extent[1] if extent else start + 1000.0)
        if not start < end:
            raise HTTPException(422, f"from_m {start:g} must be below to_m {end:g}")
        profiles = [
            None if each is None else _run_profile(session, web.store, each, start, end, columns)
            for each in (shown, previous)
        ]
        level_m = choose_level(start, end, columns)
        factor = gathered(level_m, start, end, columns)
        masts = _masts(session, found, start, end)
        wire_types = {m.wire_type for m in masts}
        if shown is not None and shown.processing is not None and shown.processing.wire_type:
            wire_types.add(shown.processing.wire_type)
        return TrackProfileOut(
            line=line,
            track=track,
            from_m=start,
            to_m=end,
            columns=columns,
            level_m=level_m,
            bin_m=None if level_m is None else level_m * factor,
            resolution=resolution(level_m),
            extent_m=list(extent) if extent else None,
            latest=profiles[0],
            previous=profiles[1],
            limits=_limits(web, wire_types),
            masts=MastsOut(
                mast=[m.code for m in masts],
                chainage_m=[m.chainage_m for m in masts],
                wire_type=[m.wire_type for m in masts],
                design_stagger_mm=[m.design_stagger_mm for m in masts],
                design_height_mm=[m.design_height_mm for m in masts],
            ),
            alerts=_alerts(session, found, start, end),
        )
