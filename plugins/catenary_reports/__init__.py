"""Built-in reports and exports, run by ``catenary report NAME`` (or a scheduled job):

- ``run``: one run, HTML with plots along the chainage, limit exceedances and the span table;
- ``maintenance``: open alerts, forecasts and the spans to visit, per line, HTML or CSV;
- ``linear-events``: per-span results as linear events for asset management, CSV or Parquet;
- ``repeatability``: two runs over the same section compared (the paper's figure 16);
- ``trends``: the worst wear rates and the spans due within the planning horizon, HTML or CSV;

and the ``history`` command (a span's measurements over runs, its wear rate and forecasts).

The hook only registers; each reporter's module (and matplotlib) is imported when it writes.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path

from catenary.plugins import hookimpl
from catenary.plugins.types import Command, Reporter, ReportRequest

__all__ = ["catenary_commands", "catenary_reporters"]


def _lazy(module: str) -> Callable[[ReportRequest, Path], Path]:
    """``catenary_reports.<module>.write``, imported on the first call."""

    def write(request: ReportRequest, output: Path) -> Path:
        found: Callable[[ReportRequest, Path], Path]
        found = importlib.import_module(f"catenary_reports.{module}").write
        return found(request, output)

    return write


@hookimpl
def catenary_commands() -> list[Command]:
    from catenary_reports.commands import history

    return [Command("history", history)]


@hookimpl
def catenary_reporters() -> list[Reporter]:
    return [
        Reporter(
            name="run",
            description=(
                "one run (RUN): header, thickness/height/stagger along the chainage, limit "
                "exceedances, spans; .html, or .csv/.xlsx/.parquet (the span table with its "
                "limit; -o -: CSV to standard output); "
                "option (--set KEY=VALUE) segment_m 1000 (chainage per figure, 50 to 1000000)"
            ),
            write=_lazy("run_report"),
        ),
        Reporter(
            name="maintenance",
            description=(
                "open alerts by urgency, forecasts and the spans to visit with their hot spots "
                "([--line L [--track T]]); .html, or .csv/.xlsx/.parquet (the spans to visit)"
            ),
            write=_lazy("maintenance"),
        ),
        Reporter(
            name="linear-events",
            description=(
                "per-span results as linear events, one row per span, wire and measure "
                "([--line L [--track T]] [RUN|--latest]; default: the latest run of every "
                "track); .csv, .xlsx or .parquet"
            ),
            write=_lazy("linear_events"),
        ),
        Reporter(
            name="repeatability",
            description=(
                "two runs over the same section (RUN_A RUN_B): thickness curves and the "
                "histogram of differences; .html, or .csv/.xlsx/.parquet (the histogram); "
                "options (--set KEY=VALUE) tolerance_mm 0.1 (0.001 to 5), "
                "bin_mm 0.02 (0.001 to 1), max_shift_m 1.0 (0 to 10)"
            ),
            write=_lazy("repeatability"),
        ),
        Reporter(
            name="trends",
            description=(
                "the worst wear rates (span-wires, mm/year with their interval) and the spans "
                "forecast to reach a limit within the horizon ([maintenance] horizon_days) "
                "([--line L [--track T]]); .html, or .csv/.parquet (one row per span-wire of "
                "either list); option (--set KEY=VALUE) top 20 (1 to 10000)"
            ),
            write=_lazy("trend_report"),
        ),
    ]
