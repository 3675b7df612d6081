"""The repeatability report: two runs over the same section (the paper's figure 16).

``catenary.measurement.compare.compare_profiles`` pairs the runs' wires, finds their chainage shift
and takes B's residual thickness minus A's at every sample of A. ``.html``: both runs' facts, the
comparison's figures (points, share within the tolerance, RMS, p95, max, shift), (a) both
runs' residual thickness along the chainage with the difference below it and (b) the
histogram of the differences; ``.csv``/``.xlsx``/``.parquet``: the histogram over every difference
(``from_mm``, ``to_mm``, ``count``, ``share``). Options: ``tolerance_mm`` (0.1, the paper's),
``bin_mm`` (0.02), ``max_shift_m`` (1.0).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow as pa

from catenary.errors import UserError
from catenary.measurement.compare import Comparison, compare_profiles
from catenary.measurement.envelope import EnvelopeGrid
from catenary.measurement.samples import export_table, run_profile
from catenary.plugins import ReportRequest
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import Run
from catenary.storage.runs import find_run, latest_processing
from catenary.storage.store import open_store
from catenary_reports import html
from catenary_reports.plots import (
    PLOT_COLUMNS,
    Boundary,
    LimitLine,
    Panel,
    Series,
    histogram_figure,
    profile_figure,
    svg,
)
from catenary_reports.request import Option, check_output, parse_request

__all__ = ["HISTOGRAM_SCHEMA", "write"]

OPTIONS = {
    "tolerance_mm": Option(0.1, 0.001, 5.0, "mm"),
    "bin_mm": Option(0.02, 0.001, 1.0, "mm"),
    "max_shift_m": Option(1.0, 0.0, 10.0, "m"),
}
"""``--set``: the tolerance and the histogram's bins within what a residual thickness can
differ by (a bin of less than a micrometre would only multiply the histogram's rows), and the
chainage shift searched within what an encoder's error amounts to (the search's work grows
with it)."""

HISTOGRAM_SCHEMA = pa.schema(
    [
        ("from_mm", pa.float64()),
        ("to_mm", pa.float64()),
        ("count", pa.int64()),
        # a fraction of the points: its decimals in CSV (catenary.measurement.spreadsheet)
        pa.field("share", pa.float64(), metadata={"unit": "fraction"}),
    ]
)

_A_COLOURS = ("#9cc3e6", "#a8d8c8")  # light and wide under B's, so both show where they agree
_B_COLOURS = ("#d9600f", "#7b3fa0")


def _histogram(comparison: Comparison) -> pa.Table:
    edges, counts = comparison.histogram()
    return pa.table(
        {
            "from_mm": edges[:-1],
            "to_mm": edges[1:],
            "count": counts,
            "share": counts / max(comparison.points, 1),
        },
        schema=HISTOGRAM_SCHEMA,
    )


def _run_facts(run: Run) -> list[str]:
    rig = run.rig_calibration
    return [
        str(run.id),
        html.stamp(run.started_at),
        f"{run.direction} chainage",
        run.vehicle.name,
        f"{rig.name} version {rig.version}",
        f"{latest_processing(run).length_m:.1f} m",
    ]


def _profile_figure(comparison: Comparison, a: Run, b: Run, masts: list[Boundary]) -> str:
    c = comparison.chainage_m
    low, high = float(c.min()), float(c.max())
    length = max(high - low, 1.0)
    grid = EnvelopeGrid(low, length / PLOT_COLUMNS, PLOT_COLUMNS, ["a", "b", "d"])
    pair_of = {wa: i for i, (wa, _) in enumerate(comparison.wire_pairs)}
    index = np.array([pair_of[int(w)] for w in comparison.wire], dtype=np.int64)
    t, d = comparison.residual_thickness_mm, comparison.difference_mm
    grid.add(c, index, {"a": t, "b": t + d, "d": d})
    thickness, difference = [], []
    for i, (wa, wb) in enumerate(comparison.wire_pairs):
        ca, cb = _A_COLOURS[i % 2], _B_COLOURS[i % 2]
        thickness.append(Series(i, "a", ca, f"run {a.id} (A) wire {wa}", width=3.2))
        thickness.append(Series(i, "b", cb, f"run {b.id} (B) wire {wb}"))
        difference.append(Series(i, "d", "#3b4450", "B − A"))
    tol = comparison.tolerance_mm
    band = [
        LimitLine(sign * tol, "urgent", f"{sign * tol:+.2f} mm", panel=1) for sign in (1.0, -1.0)
    ]
    fig = profile_figure(
        grid,
        0,
        PLOT_COLUMNS,
        [
            Panel("residual thickness [mm]", tuple(thickness)),
            Panel("difference B − A [mm]", tuple(difference)),
        ],
        boundaries=masts,
        limits=band,
    )
    return svg(fig, "repeatability-profile")


def _histogram_figure(comparison: Comparison) -> tuple[str, str]:
    tol, width = comparison.tolerance_mm, comparison.bin_mm
    half = min(max(2.0 * tol, comparison.p95_mm), 20.0 * width)
    edges, counts = comparison.histogram(width, half)
    d = np.asarray(comparison.difference_mm)
    below = int(np.count_nonzero(d < edges[0]))
    above = int(np.count_nonzero(d > edges[-1]))
    share = 100.0 * comparison.share_within()
    title = f"within ±{tol:.2f} mm: {share:.1f} % of {comparison.points} points"
    fig = histogram_figure(edges, counts, comparison.points, tol, title)
    caption = (
        f"Bins of {width:g} mm over ±{edges[-1]:.2f} mm; {below} points below and {above} above "
        "that range are not drawn (the CSV holds every bin). Dashed lines: the tolerance."
    )
    return svg(fig, "repeatability-histogram"), caption


def write(raw: ReportRequest, output: Path) -> Path:
    """Write the repeatability report of ``raw['runs']`` (A, B) to ``output``."""
    request = parse_request(
        "repeatability",
        raw,
        runs=(2, 2),
        options=OPTIONS,
    )
    suffix = check_output(output, (".html", ".csv", ".xlsx", ".parquet"))
    settings, options = request.settings, request.options
    with (
        open_database(settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        a, b = (find_run(session, reference) for reference in request.runs)
        if a.track_id != b.track_id:
            raise UserError(f"runs {a.id} and {b.id} are on different tracks")
        store = open_store(settings)
        profiles = run_profile(store, a), run_profile(store, b)
        facts = list(zip(_run_facts(a), _run_facts(b), strict=True))
        boundaries: dict[float, str | None] = {}
        for s in a.span_measurements:
            boundaries.setdefault(s.start_chainage_m, s.mast_from)
            boundaries.setdefault(s.end_chainage_m, s.mast_to)
        line = f"line {a.line.code}, track {a.track.code if a.track else '-'}"
    try:
        comparison = compare_profiles(
            *profiles,
            max_shift_m=options["max_shift_m"],
            tolerance_mm=options["tolerance_mm"],
            bin_mm=options["bin_mm"],
        )
    except UserError as exc:
        raise UserError(f"runs {a.id} and {b.id}: {exc}") from None
    if suffix != ".html":
        export_table(iter([_histogram(comparison)]), HISTOGRAM_SCHEMA, output)
        return output
    masts = [Boundary(c, label) for c, label in sorted(boundaries.items())]
    histogram, caption = _histogram_figure(comparison)
    share = comparison.share_within()
    pairs = ", ".join(f"A wire {wa} with B wire {wb}" for wa, wb in comparison.wire_pairs)
    labels = ["run", "date", "direction", "vehicle", "rig calibration", "length"]
    results = [
        ("Points compared", f"{comparison.points} ({pairs})"),
        ("Within tolerance", f"{100.0 * share:.1f} % within ±{comparison.tolerance_mm:.2f} mm"),
        (
            "Difference B − A",
            f"mean {comparison.mean_mm:+.3f} mm, RMS {comparison.rms_mm:.3f} mm, "
            f"p95 {comparison.p95_mm:.3f} mm, max {comparison.max_abs_mm:.3f} mm",
        ),
        (
            "Chainage shift",
            f"{comparison.shift_m:+.3f} m (B minus A), stagger RMS "
            f"{comparison.stagger_rms_mm:.2f} mm at it",
        ),
    ]
    verdict = "meets" if math.isfinite(share) and share >= 0.9 else "misses"
    sections = [
        html.section(
            "Runs",
            html.table(
                ["", "run A", "run B"],
                [[label, x, y] for label, (x, y) in zip(labels, facts, strict=True)],
                table_id="runs",
            ),
            section_id="runs",
        ),
        html.section(
            "Result",
            html.facts(results, table_id="result"),
            html.note(
                f"The paper's repeatability: more than 90 % of the points within 0.1 mm; this "
                f"comparison {verdict} 90 % within ±{comparison.tolerance_mm:.2f} mm."
            ),
            section_id="result-section",
        ),
        html.section(
            "(a) Residual thickness of both runs",
            f"<figure>{_profile_figure(comparison, a, b, masts)}<figcaption>B is drawn at A's "
            "chainage (its shift removed); each pixel column shows the lowest and highest value "
            f"of its points; dashed lines in the lower panel: ±{comparison.tolerance_mm:.2f} mm."
            "</figcaption></figure>",
            section_id="profile",
        ),
        html.section(
            "(b) Differences between the runs",
            f'<figure class="narrow">{histogram}<figcaption>{html.escape(caption)}</figcaption>'
            "</figure>",
            section_id="histogram",
        ),
    ]
    title = f"Repeatability: runs {a.id} and {b.id}"
    return html.write_text(output, html.page(title, line, sections))
