"""The run report: one run's facts, its plots along the chainage, limit exceedances and spans.

``.html``: the header facts (line, track, direction, date, vehicle, rig calibration, length,
chainage as stored), residual thickness, stagger and height along the chainage per wire (the
paper's figures 14-15) in figures of at most ``segment_m`` of chainage each, span boundaries
and mast codes marked, the policy's limits drawn and each span's minimum marked; the spans
whose minimum residual thickness meets a local limit of the configured policy, most severe
first (without a policy, the thinnest spans); the line-scan crops at the minima of the spans
beyond a limit and of the thinnest others; the track's previous complete run beside this one
(its date, each span's minimum then and now, the wear since in mm and mm/year, most worn
first: ``catenary.maintenance.trends``); and every span and wire. ``.csv``/``.xlsx``/
``.parquet`` (``-``: CSV to standard output): the span table (the ``spans`` export's columns)
with the most severe local limit each row meets.

The samples file is read twice, row group by row group (its chainage range, then the
envelopes): memory is bounded by the plots' columns, not by the run's length. Samples with a
vehicle sensor fault are left out of the plots as they are of the span figures.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from sqlalchemy.orm import Session

from catenary.limits import LEVELS, LimitPolicy, Threshold, thresholds
from catenary.maintenance.trends import (
    RunComparison,
    TrackTrends,
    compare_with_previous,
    track_trends,
)
from catenary.measurement.envelope import EnvelopeGrid
from catenary.measurement.evidence import evidence_key
from catenary.measurement.samples import (
    TRUST_COLUMNS,
    StoredSamples,
    export_table,
    read_sample_batches,
    run_samples,
    trusted,
)
from catenary.measurement.spans import SPAN_COLUMNS, SPAN_SCHEMA
from catenary.plugins import PluginRegistry, ReportRequest
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import Run, SpanMeasurement
from catenary.storage.runs import alignment_summary, find_run, latest_processing
from catenary.storage.store import Store, open_store
from catenary_reports import html
from catenary_reports.html import Cell, number
from catenary_reports.plots import (
    PLOT_COLUMNS,
    Boundary,
    LimitLine,
    Marker,
    Panel,
    Series,
    profile_figure,
    svg,
    wire_colour,
)
from catenary_reports.request import Option, check_output, parse_request

__all__ = ["exceeded", "write"]

THINNEST = 20
"""Spans listed by minimum residual thickness when no policy is configured."""

PANELS = (
    ("residual_thickness_mm", "residual thickness [mm]"),
    ("stagger_mm", "stagger [mm]"),
    ("height_mm", "height above rail [mm]"),
)


@dataclass(frozen=True)
class _Limits:
    """The policy's thresholds per wire type of the run, and the wire types it cannot judge."""

    policy: LimitPolicy | None
    by_type: dict[str, list[Threshold]]
    unknown_types: tuple[str, ...]


def _limits(registry: PluginRegistry, policy: LimitPolicy | None, types: set[str]) -> _Limits:
    known = registry.wire_types()
    by_type: dict[str, list[Threshold]] = {}
    if policy is not None:
        for name in sorted(types & set(known)):
            by_type[name] = thresholds(known[name], policy)
    return _Limits(policy, by_type, tuple(sorted(types - set(known))))


def exceeded(row: SpanMeasurement, found: Sequence[Threshold]) -> Threshold | None:
    """The most severe local threshold that the row's minimum residual thickness meets."""
    met = [
        t
        for t in found
        if t.scope == "local"
        and (
            row.min_residual_thickness_mm <= t.residual_thickness_mm
            if t.rule.inclusive
            else row.min_residual_thickness_mm < t.residual_thickness_mm
        )
    ]
    return max(met, key=lambda t: LEVELS.index(t.level), default=None)


def _masts(row: SpanMeasurement) -> str:
    return f"{row.mast_from} to {row.mast_to}" if row.mast_from else f"span {row.span}"


def _span_cells(s: SpanMeasurement) -> list[Cell | str]:
    """A span's masts, chainages, wire, wire type and minimum: the tables' common cells."""
    return [
        Cell(_masts(s), keep=True),
        number(s.start_chainage_m, 1),
        number(s.end_chainage_m, 1),
        Cell(str(s.wire_position), numeric=True),
        s.wire_type,
        number(s.min_residual_thickness_mm),
        number(s.min_at_chainage_m, 1),
    ]


def _facts(run: Run, spans: Sequence[SpanMeasurement], extent: _Extent) -> list[tuple[str, str]]:
    rig = run.rig_calibration
    processing = latest_processing(run)
    line = run.line.code + (f" ({run.line.name})" if run.line.name else "")
    if any(s.mast_from for s in spans):
        first = min(spans, key=lambda s: s.start_chainage_m)
        last = max(spans, key=lambda s: s.end_chainage_m)
        cut = f"at the mast register's masts, {first.mast_from} to {last.mast_to}"
    else:
        cut = "at the stagger's turning points (no mast register)"
    chainage = (
        f"{extent.low_m:.1f} to {extent.high_m:.1f} m, as stored with the samples"
        if extent.samples
        else "no samples"
    )
    alignment = alignment_summary(processing)
    if alignment:
        chainage += f"; {alignment}"
    samples = f"{extent.rows} in {extent.path.name}"
    left_out = [
        f"{count} {what}"
        for count, what in (
            (extent.faulty, "with a vehicle sensor fault"),
            (extent.uncertain, "not surely the contact wire (selection uncertain)"),
        )
        if count
    ]
    if left_out:
        samples += f" ({', '.join(left_out)}: left out)"
    return [
        ("Run", f"{run.id} ({run.status}), UUID {run.uuid}"),
        ("Line", line),
        ("Track", run.track.code if run.track else "-"),
        ("Direction", f"{run.direction} chainage"),
        ("Date", html.stamp(run.started_at)),
        (
            "Processed",
            f"{html.stamp(processing.processed_at)} by {processing.processor} "
            f"(catenary {processing.package_version}, settings SHA-256 "
            f"{processing.settings_sha256[:12]}; processing {processing.uuid})",
        ),
        ("Vehicle", run.vehicle.name),
        (
            "Rig calibration",
            f"{rig.name} version {rig.version} (SHA-256 {rig.sha256[:12]}, "
            f"{html.stamp(rig.created_at)})",
        ),
        ("Length", f"{processing.length_m:.1f} m, {run.scans} scans"),
        ("Chainage", chainage),
        ("Spans", f"{len({s.span for s in spans})} ({len(spans)} span-wires), cut {cut}"),
        ("Wire types", ", ".join(sorted({s.wire_type for s in spans})) or "-"),
        ("Samples", samples),
        ("Source file", f"{run.source_file} (SHA-256 {run.source_sha256[:12]})"),
    ]


@dataclass(frozen=True)
class _Extent:
    """The chainage range of a run's usable samples (``trusted``: no vehicle sensor fault,
    surely the contact wire), how many there are, how many rows the file holds, and how many
    of them have a vehicle sensor fault and how many are ``selection_uncertain``."""

    path: StoredSamples
    low_m: float
    high_m: float
    samples: int
    rows: int
    faulty: int
    uncertain: int


def _extent(path: StoredSamples) -> _Extent:
    low, high, usable, rows, faulty, uncertain = math.inf, -math.inf, 0, 0, 0, 0
    for batch in read_sample_batches(path, ["chainage_m", *TRUST_COLUMNS]):
        c = batch["chainage_m"][trusted(batch)]
        c = c[np.isfinite(c)]
        rows += int(batch["vehicle_fault"].shape[0])
        faulty += int(np.count_nonzero(batch["vehicle_fault"]))
        uncertain += int(np.count_nonzero(batch["selection_uncertain"]))
        usable += int(c.shape[0])
        if c.shape[0]:
            low, high = min(low, float(c.min())), max(high, float(c.max()))
    return _Extent(path, low, high, usable, rows, faulty, uncertain)


def _grid(extent: _Extent, segment_m: float) -> tuple[EnvelopeGrid, int]:
    """The envelopes of the run's usable samples, and the number of figures they fill."""
    span_m = max(extent.high_m - extent.low_m, 1.0)
    figures = max(1, math.ceil(span_m / segment_m - 1e-9))
    bin_m = span_m / (figures * PLOT_COLUMNS)
    start = extent.low_m if extent.high_m > extent.low_m else extent.low_m - 0.5
    grid = EnvelopeGrid(start, bin_m, figures * PLOT_COLUMNS, [q for q, _ in PANELS])
    columns = ["chainage_m", "wire", *TRUST_COLUMNS, *grid.quantities]
    for batch in read_sample_batches(extent.path, columns):
        good = trusted(batch)
        grid.add(
            batch["chainage_m"][good],
            batch["wire"][good],
            {q: batch[q][good].astype(np.float64) for q in grid.quantities},
        )
    return grid, figures


def _limit_lines(limits: _Limits) -> list[LimitLine]:
    several = len(limits.by_type) > 1
    lines = []
    for wire_type, found in limits.by_type.items():
        for t in found:
            average = t.scope != "local"
            label = f"{t.level} {t.residual_thickness_mm:.2f} mm"
            label += f" ({wire_type})" if several else ""
            label += " (anchor-section average)" if average else ""
            lines.append(LimitLine(t.residual_thickness_mm, t.level, label, dotted=average))
    return lines


def _figures(
    extent: _Extent, spans: Sequence[SpanMeasurement], limits: _Limits, segment_m: float
) -> list[str]:
    if not extent.samples:
        return [html.note("The run has no usable samples to plot.")]
    grid, figures = _grid(extent, segment_m)
    boundaries: dict[float, str | None] = {}
    for s in spans:
        boundaries.setdefault(s.start_chainage_m, s.mast_from)
        boundaries.setdefault(s.end_chainage_m, s.mast_to)
    marks = [Boundary(c, label) for c, label in sorted(boundaries.items())]
    minima = [
        Marker(s.min_at_chainage_m, s.min_residual_thickness_mm, wire_colour(s.wire)) for s in spans
    ]
    panels = [
        Panel(label, tuple(Series(w, q, wire_colour(w), f"run wire {w}") for w in grid.wires))
        for q, label in PANELS
    ]
    lines = _limit_lines(limits)
    parts = []
    for index in range(figures):
        first, last = index * PLOT_COLUMNS, (index + 1) * PLOT_COLUMNS
        low = grid.start_m + first * grid.bin_m
        high = grid.start_m + last * grid.bin_m
        inside = [b.label for b in marks if low <= b.chainage_m <= high and b.label]
        masts = f" (masts {inside[0]} to {inside[-1]})" if inside else ""
        fig = profile_figure(
            grid, first, last, panels, boundaries=marks, limits=lines, markers=minima
        )
        parts.append(
            html.heading(f"Chainage {low:.1f} to {high:.1f} m{masts}", f"plot-{index + 1}")
            + f"<figure>{svg(fig, f'run-figure-{index}')}<figcaption>"
            "Each pixel column shows the lowest and highest value of its samples "
            f"({grid.bin_m:.2f} m of chainage), so no local minimum is lost; squares mark "
            "each span's minimum; dashed vertical lines are the span boundaries (masts)."
            "</figcaption></figure>"
        )
    return parts


def _exceedance_section(spans: Sequence[SpanMeasurement], limits: _Limits) -> str:
    if limits.policy is None:
        thinnest = sorted(spans, key=lambda s: s.min_residual_thickness_mm)[:THINNEST]
        rows: list[list[Cell | str]] = [
            [*_span_cells(s), number(s.mean_residual_thickness_mm)] for s in thinnest
        ]
        return html.section(
            "Thinnest spans",
            html.note(
                "No wear-limit policy is configured ([limits] policy in the config, or "
                f"--policy NAME), so no limit is applied: the {len(thinnest)} spans with the "
                f"lowest minimum residual thickness of {len(spans)}."
            ),
            html.table(
                [
                    "masts",
                    "from m",
                    "to m",
                    "wire position",
                    "wire type",
                    "min mm",
                    "at m",
                    "mean mm",
                ],
                rows,
                table_id="exceedances",
            ),
            section_id="exceedance",
        )
    found = []
    for s in spans:
        t = exceeded(s, limits.by_type.get(s.wire_type, ()))
        if t is not None:
            found.append((s, t))
    found.sort(key=lambda p: (-LEVELS.index(p[1].level), p[0].min_residual_thickness_mm))
    rows = [
        [
            Cell(markup=html.tag(t.level)),
            *_span_cells(s),
            number(t.residual_thickness_mm),
            number(s.min_residual_thickness_mm - t.residual_thickness_mm),
            f"rule {t.rule_number}: {t.action or t.rule.criterion}",
        ]
        for s, t in found
    ]
    policy = limits.policy
    notes = [
        html.note(
            f"Policy {policy.name}: {policy.description}. Local rules are applied to each span's "
            "minimum residual thickness; anchor-section average rules are drawn as dotted "
            "lines but not applied to single spans."
        )
    ]
    if limits.unknown_types:
        notes.append(
            html.note(f"Wire types not registered, not judged: {', '.join(limits.unknown_types)}")
        )
    return html.section(
        "Limit exceedances",
        *notes,
        html.table(
            [
                "level",
                "masts",
                "from m",
                "to m",
                "wire position",
                "wire type",
                "min mm",
                "at m",
                "limit mm",
                "margin mm",
                "action",
            ],
            rows,
            row_classes=[t.level for _, t in found],
            table_id="exceedances",
            empty=f"No span meets a local limit of policy {policy.name}.",
        ),
        section_id="exceedance",
    )


def _span_section(spans: Sequence[SpanMeasurement], limits: _Limits) -> str:
    wires: dict[int, int] = {}
    for s in spans:
        wires[s.span] = wires.get(s.span, 0) + 1
    rows: list[list[Cell | str]] = []
    classes: list[str] = []
    for s in spans:
        t = exceeded(s, limits.by_type.get(s.wire_type, ()))
        classes.append(t.level if t is not None else "")
        rows.append(
            [
                Cell(str(s.span), numeric=True),
                Cell(_masts(s), keep=True),
                number(s.start_chainage_m, 1),
                number(s.end_chainage_m, 1),
                number(s.end_chainage_m - s.start_chainage_m, 1),
                Cell(str(s.wire_position), numeric=True),
                s.wire_type,
                number(s.min_residual_thickness_mm),
                number(s.min_at_chainage_m, 1),
                number(s.mean_residual_thickness_mm),
                f"{s.height_min_mm:.0f} to {s.height_max_mm:.0f}",
                f"{s.stagger_min_mm:.0f} to {s.stagger_max_mm:.0f}",
                Cell(str(s.samples), numeric=True),
                "overlap" if wires[s.span] > 1 else "",
                Cell(markup=html.tag(t.level)) if t is not None else "",
            ]
        )
    return html.section(
        "Spans",
        html.note(
            "One row per span and contact wire (the spans export); an overlap is a span with "
            "two contact wires; heights above top of rail, staggers in the track frame "
            "(positive to the right looking in the direction of travel)."
        ),
        html.table(
            [
                "span",
                "masts",
                "from m",
                "to m",
                "length m",
                "wire position",
                "wire type",
                "min mm",
                "at m",
                "mean mm",
                "height mm",
                "stagger mm",
                "samples",
                "hot spot",
                "limit",
            ],
            rows,
            row_classes=classes,
            table_id="spans",
        ),
        section_id="span-table",
    )


def _previous_section(run: Run, found: tuple[TrackTrends, RunComparison] | None) -> str:
    """The track's previous complete run beside this one: per span and wire position the
    minimum residual thickness then and now, and the wear since, worst first."""
    title, section_id = "Since the previous run", "previous-run"
    if found is None:
        where = f"line {run.line.code} track {run.track.code}" if run.track else "no track"
        return html.section(
            title,
            html.note(f"No earlier complete run of {where} to compare with."),
            section_id=section_id,
        )
    trends, c = found
    data, rows = trends.data, trends.data.rows
    started = data.run_started[int(np.searchsorted(data.run_id, c.previous_run_id))]
    codes = data.mast_code
    table: list[list[Cell | str]] = []
    for now, then, wear, rate, repaired in zip(
        c.now.tolist(),
        c.then.tolist(),
        c.wear_mm.tolist(),
        c.wear_mm_per_year.tolist(),
        c.repaired.tolist(),
        strict=True,
    ):
        mast_from, mast_to = int(rows.mast_from[now]), int(rows.mast_to[now])
        masts = f"{codes[mast_from]} to {codes[mast_to]}" if mast_from >= 0 else ""
        table.append(
            [
                Cell(masts or f"span {rows.span[now]}", keep=True),
                number(float(rows.start_m[now]), 1),
                number(float(rows.end_m[now]), 1),
                Cell(str(trends.histories.row_position[now]), numeric=True),
                number(float(rows.min_thickness_mm[then])),
                number(float(rows.min_thickness_mm[now])),
                number(wear),
                number(rate, 3),
                "repaired since" if repaired else "",
            ]
        )
    return html.section(
        title,
        html.facts(
            [
                ("Previous run", f"{c.previous_run_id}, {html.stamp(started)}"),
                ("Between the runs", f"{c.years * 365.25:.1f} days"),
                ("Span-wires in both", str(len(table))),
            ],
            table_id="previous-facts",
        ),
        html.note(
            "Each span and wire position measured by both runs (wire positions count from the "
            "left looking towards increasing chainage, whatever the direction of the runs), "
            "the most worn since first; a negative wear is a thicker wire (a repair, or the "
            "measurement's scatter)."
        ),
        html.table(
            [
                "masts",
                "from m",
                "to m",
                "wire position",
                "min mm then",
                "min mm now",
                "wear mm",
                "wear mm/year",
                "",
            ],
            table,
            table_id="previous",
            empty="The two runs measured no span in common.",
        ),
        section_id=section_id,
    )


def _previous(
    session: Session, registry: PluginRegistry, run: Run
) -> tuple[TrackTrends, RunComparison] | None:
    if run.track_id is None:
        return None
    trends = track_trends(session, run.track_id, registry.wire_types(), None)
    comparison = compare_with_previous(trends, run.id)
    return None if comparison is None else (trends, comparison)


OPTIONS = {"segment_m": Option(1000.0, 50.0, 1_000_000.0, "m")}
"""``--set``: the chainage of one figure, at least about a span (a figure of less would
multiply the figures, and the time, without showing more)."""

_TABLE_SCHEMA = pa.schema(
    [
        *SPAN_SCHEMA,
        pa.field("limit_policy", pa.string()),
        pa.field("limit_level", pa.string()),
        pa.field("limit_residual_thickness_mm", pa.float64()),
        pa.field("limit_action", pa.string()),
    ]
)


def _table(spans: Sequence[SpanMeasurement], limits: _Limits) -> pa.Table:
    columns: dict[str, list[Any]] = {c: [getattr(s, c) for s in spans] for c in SPAN_COLUMNS}
    met = [exceeded(s, limits.by_type.get(s.wire_type, ())) for s in spans]
    policy = limits.policy.name if limits.policy is not None else None
    columns["limit_policy"] = [policy] * len(spans)
    columns["limit_level"] = [t.level if t else None for t in met]
    columns["limit_residual_thickness_mm"] = [t.residual_thickness_mm if t else None for t in met]
    columns["limit_action"] = [(t.action or t.rule.criterion) if t else None for t in met]
    return pa.table(columns, schema=_TABLE_SCHEMA)


def write(raw: ReportRequest, output: Path) -> Path:
    """Write the run report of ``raw['runs'][0]`` to ``output`` (module docstring)."""
    request = parse_request("run", raw, runs=(1, 1), options=OPTIONS)
    suffix = check_output(output, (".html", ".csv", ".xlsx", ".parquet"))
    settings = request.settings
    with (
        open_database(settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        run = find_run(session, request.runs[0])
        spans = list(run.span_measurements)
        limits = _limits(request.registry, request.policy, {s.wire_type for s in spans})
        if suffix != ".html":
            export_table(iter([_table(spans, limits)]), _TABLE_SCHEMA, output)
            return output
        store = open_store(settings)
        extent = _extent(run_samples(store, run))
        evidence = _evidence_section(store, latest_processing(run).uuid, spans, limits)
        facts = _facts(run, spans, extent)
        previous = _previous_section(run, _previous(session, request.registry, run))
        title = f"Run {run.id}: line {run.line.code}, track {run.track.code if run.track else '-'}"
        subtitle = (
            f"{run.direction} chainage, {html.stamp(run.started_at)}, vehicle {run.vehicle.name}"
        )
    policy = (
        f"{limits.policy.name}: {limits.policy.description}" if limits.policy else "none configured"
    )
    sections = [
        html.section("Run", html.facts([*facts, ("Wear-limit policy", policy)]), section_id="run"),
        html.section(
            "Residual thickness, stagger and height along the chainage",
            *_figures(extent, spans, limits, request.options["segment_m"]),
            section_id="plots",
        ),
        _exceedance_section(spans, limits),
        evidence,
        previous,
        _span_section(spans, limits),
    ]
    return html.write_text(output, html.page(title, subtitle, sections, toc=True))


def _evidence_section(
    store: Store, processing_uuid: str, spans: Sequence[SpanMeasurement], limits: _Limits
) -> str:
    """The line-scan crops at the minima of the spans beyond a limit and of the ``THINNEST``
    thinnest others (``catenary.measurement.evidence``), thinnest first."""
    beyond = [s for s in spans if exceeded(s, limits.by_type.get(s.wire_type, [])) is not None]
    chosen_ids = {id(s) for s in beyond}
    others = sorted(
        (s for s in spans if id(s) not in chosen_ids), key=lambda s: s.min_residual_thickness_mm
    )
    chosen = sorted([*beyond, *others[:THINNEST]], key=lambda s: s.min_residual_thickness_mm)
    figures, missing = [], 0
    for s in chosen:
        key = evidence_key(processing_uuid, s.span, s.wire)
        if not store.exists(key):
            missing += 1
            continue
        with store.open_input(key) as handle:
            data = base64.b64encode(handle.read()).decode("ascii")
        figures.append(
            '<figure class="evidence"><img alt="line-scan crop" style="width: 100%; '
            f'height: 10em; image-rendering: pixelated" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(_masts(s))}, wire position {s.wire_position}: "
            f"{s.min_residual_thickness_mm:.2f} mm at chainage {s.min_at_chainage_m:.1f} m"
            "</figcaption></figure>"
        )
    notes = [
        "Every camera's lines a metre around each span's thinnest point (scans downwards, "
        "cameras side by side, each one's levels stretched): the spans beyond a limit and the "
        f"{THINNEST} thinnest others."
    ]
    if missing:
        notes.append(f"{missing} of them have no crop (processed before crops were kept).")
    return html.section(
        "Image evidence", html.note(" ".join(notes)), *figures, section_id="evidence"
    )
