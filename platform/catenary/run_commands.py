"""The commands on runs: ``catenary process``, ``catenary export`` and ``catenary compare``."""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click
import numpy as np
import pyarrow as pa
from sqlalchemy import select

from catenary.compare import compare_profiles
from catenary.config import Settings
from catenary.domain import RunHeader
from catenary.errors import UserError
from catenary.run_samples import run_profile, samples_file
from catenary.samples import export_schema, export_table, sample_tables
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import SpanMeasurement
from catenary.storage.runs import find_run

if TYPE_CHECKING:
    from catenary.cli import App
    from catenary.process import ProcessResult

F = TypeVar("F", bound=Callable[..., Any])

SPAN_COLUMNS = (
    "span",
    "mast_from",
    "mast_to",
    "start_chainage_m",
    "end_chainage_m",
    "wire",
    "wire_type",
    "min_residual_thickness_mm",
    "min_at_chainage_m",
    "mean_residual_thickness_mm",
    "height_min_mm",
    "height_max_mm",
    "stagger_min_mm",
    "stagger_max_mm",
    "samples",
)
"""The ``spans`` export's columns (FORMATS.md), in order."""


def database_option(command: F) -> F:
    """``--db URL`` on a command, as the global option does."""
    return click.option(
        "--db",
        "database_url",
        metavar="URL",
        help="Database URL (default: the global --db, $CATENARY_DATABASE_URL, the config).",
    )(command)


def _settings(ctx: click.Context, database_url: str | None) -> tuple[App, Settings]:
    from catenary.cli import app_of  # the CLI module imports this one

    app = app_of(ctx)
    settings = app.settings
    if database_url:
        settings = dataclasses.replace(settings, database_url=database_url)
    return app, settings


def _mast_range(row: SpanMeasurement) -> str:
    if row.mast_from is None:
        return f"span {row.span}"
    return f"masts {row.mast_from} to {row.mast_to}"


def echo_summary(result: ProcessResult) -> None:
    """The short summary of a stored run, ending with its id."""
    header = result.header
    assert header is not None
    low, high = result.chainage_range_m
    click.echo(
        f"run        line {result.line} track {result.track or '-'}, {header.direction} "
        f"chainage, {header.scans} scans, {result.length_m:.1f} m ({low:.1f} to {high:.1f} m)"
    )
    alignment = result.alignment
    if alignment is not None and alignment.aligned:
        click.echo(
            f"chainage   aligned to the register: {alignment.matched} of "
            f"{alignment.turning_points} registration points on masts, residual RMS "
            f"{alignment.residual_rms_m:.2f} m (encoder error {1 / alignment.scale - 1:+.3%}, "
            f"start {header.start_chainage_m:.1f} m -> "
            f"{alignment.chainage_m(np.zeros(1))[0]:.1f} m)"
        )
    elif alignment is not None:
        click.echo(f"chainage   start + encoder distance ({alignment.reason})")
    wires = "" if result.span_rows == result.spans else f" ({result.span_rows} span-wires)"
    click.echo(f"spans      {result.spans}{wires}")
    if result.minimum is not None:
        m = result.minimum
        click.echo(
            f"minimum    residual thickness {m.min_residual_thickness_mm:.2f} mm "
            f"({m.wire_type}) at chainage {m.min_at_chainage_m:.1f} m, {_mast_range(m)}, "
            f"wire {m.wire}"
        )
    notes = []
    if result.outside_spans:
        notes.append(f"{result.outside_spans} outside the register's spans")
    if result.faulty:
        notes.append(f"{result.faulty} with a vehicle sensor fault (not in the span figures)")
    extra = f" ({'; '.join(notes)})" if notes else ""
    click.echo(f"samples    {result.samples} in {result.samples_path}{extra}")
    if result.replaced:
        click.echo("replaced   the run's earlier results")
    if result.alerts is not None:
        click.echo(f"alerts     {result.alerts.summary()} (policy {result.alerts.policy})")
        for note in result.alerts.notes:
            click.echo(f"           {note}")
    else:
        click.echo(f"alerts     {result.alerts_note}")
    click.echo(f"stored as run {result.run_id}")


@click.command("process")
@click.argument("run_path", metavar="RUN.h5", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--rig",
    "rig_path",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="Rig calibration TOML (catenary calibrate).",
)
@click.option(
    "--masts",
    "register_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Mast register CSV: spans cut at its masts, chainage aligned to them.",
)
@click.option("--wire-type", help="Wire type of the whole run (default: the register's).")
@click.option("--line", help="Line code (default: the run file's).")
@click.option("--track", help="Track code (default: the run file's).")
@click.option(
    "--processor",
    default="linescan-stereo",
    show_default=True,
    help="Processing method (catenary plugins lists them).",
)
@click.option("--replace", is_flag=True, help="Process a run already stored again, replacing it.")
@database_option
@click.pass_context
def process(
    ctx: click.Context,
    run_path: Path,
    rig_path: Path,
    register_path: Path | None,
    wire_type: str | None,
    line: str | None,
    track: str | None,
    processor: str,
    replace: bool,
    database_url: str | None,
) -> None:
    """Process a recorded run into per-span wear in the database."""
    from catenary.process import ProcessRequest, process_run  # numerical modules on use only

    app, settings = _settings(ctx, database_url)
    request = ProcessRequest(
        run_path=run_path,
        rig_path=rig_path,
        register_path=register_path,
        wire_type=wire_type,
        line=line,
        track=track,
        processor=processor,
        replace=replace,
    )
    with ExitStack() as stack:
        bar: list[Any] = []

        def start(header: RunHeader) -> None:
            bar.append(
                stack.enter_context(
                    click.progressbar(
                        length=header.scans,
                        label="processing",
                        file=sys.stderr,
                        hidden=not sys.stderr.isatty(),  # no bar in logs
                    )
                )
            )

        result = process_run(
            request, settings, app.registry, progress=lambda n: bar[0].update(n), on_start=start
        )
    if result.already_stored:
        click.echo(
            f"{run_path} is already stored with this rig calibration as run {result.run_id}: "
            "nothing done (--replace processes it again)"
        )
        return
    echo_summary(result)


_SPAN_SCHEMA = pa.schema(
    [
        (
            c,
            pa.string()
            if c in ("mast_from", "mast_to", "wire_type")
            else pa.int64()
            if c in ("span", "wire", "samples")
            else pa.float64(),
        )
        for c in SPAN_COLUMNS
    ]
)


def _span_table(rows: list[SpanMeasurement]) -> pa.Table:
    return pa.table({c: [getattr(r, c) for r in rows] for c in SPAN_COLUMNS}, schema=_SPAN_SCHEMA)


@click.command("export")
@click.argument("run_reference", metavar="RUN")
@click.option(
    "--what",
    type=click.Choice(["samples", "spans"]),
    required=True,
    help="Full-resolution samples, or one row per span and wire.",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="FILE.csv or FILE.parquet.",
)
@database_option
@click.pass_context
def export(
    ctx: click.Context, run_reference: str, what: str, output: Path, database_url: str | None
) -> None:
    """Export a run's samples or spans (RUN: a run id or 'latest') as CSV or Parquet."""
    _, settings = _settings(ctx, database_url)
    if output.suffix.lower() not in (".csv", ".parquet"):
        raise UserError(f"{output}: the output's suffix must be .csv or .parquet")
    with open_database(settings.database_url) as engine, session_scope(engine) as session:
        run = find_run(session, run_reference)
        if what == "spans":
            rows = list(
                session.scalars(
                    select(SpanMeasurement)
                    .where(SpanMeasurement.run_id == run.id)
                    .order_by(SpanMeasurement.span, SpanMeasurement.wire)
                )
            )
            written = export_table(iter([_span_table(rows)]), _SPAN_SCHEMA, output)
        else:
            path = samples_file(settings, run)
            written = export_table(sample_tables(path), export_schema(path), output)
    click.echo(f"{written} {what} of run {run.id} written to {output}")


@click.command("compare")
@click.argument("run_a", metavar="RUN_A")
@click.argument("run_b", metavar="RUN_B")
@database_option
@click.pass_context
def compare(ctx: click.Context, run_a: str, run_b: str, database_url: str | None) -> None:
    """Repeatability: the residual thickness of two runs over the same section, point by point."""
    _, settings = _settings(ctx, database_url)
    with open_database(settings.database_url) as engine, session_scope(engine) as session:
        a, b = find_run(session, run_a), find_run(session, run_b)
        if a.track_id != b.track_id:
            raise UserError(f"runs {a.id} and {b.id} are on different tracks")
        profiles = run_profile(settings, a), run_profile(settings, b)
    try:
        comparison = compare_profiles(*profiles)
    except UserError as exc:
        raise UserError(f"runs {a.id} and {b.id}: {exc}") from None
    click.echo(f"run {a.id} against run {b.id}")
    for text in comparison.summary_lines():
        click.echo(text)


__all__ = ["SPAN_COLUMNS", "compare", "echo_summary", "export", "process"]
