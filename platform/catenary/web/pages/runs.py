"""The runs pages: ``/runs`` (filters: line, track), ``/runs/{run}`` (a run's vehicle, rig
calibration, processings and chainage alignment) and ``/runs/{run}/report`` (the reports
plugin's run report, as ``catenary report run RUN`` writes it)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Annotated
from urllib.parse import urlencode

from fastapi import APIRouter, Query, Request
from fastapi.responses import HTMLResponse
from sqlalchemy import distinct, func, select
from starlette.responses import Response

from catenary.maintenance.reports import report_request
from catenary.storage.database import session_scope
from catenary.storage.models import SpanMeasurement
from catenary.storage.runs import alignment_summary, count_runs, list_runs
from catenary.web.api.runs import run_of
from catenary.web.app import state
from catenary.web.auth import Principal, page_user, requires
from catenary.web.errors import NotFound
from catenary.web.templating import render

__all__ = ["PAGE_SIZE", "router"]

router = APIRouter()

PAGE_SIZE = 100
"""Runs on one page of the list."""

RUN_REPORTER = "run"
"""The reporter of the run report (the reports plugin's)."""

Code = Annotated[str | None, Query(max_length=64)]


@router.get("/runs")
def runs(
    request: Request,
    user: Annotated[Principal, requires("viewer", page_user)],
    line: Code = None,
    track: Code = None,
    page: Annotated[int, Query(ge=1, le=100_000)] = 1,
) -> Response:
    """The runs, newest first."""
    chosen = {k: v for k, v in (("line", line), ("track", track)) if v}

    def at(number: int) -> str:
        return "/runs?" + urlencode({**chosen, "page": number})

    with session_scope(state(request).engine, read_only=True) as session:
        where = {"line": chosen.get("line"), "track": chosen.get("track")}
        total = count_runs(session, **where)
        shown = list_runs(
            session, **where, newest_first=True, limit=PAGE_SIZE, offset=(page - 1) * PAGE_SIZE
        )
        context = {
            "runs": shown,
            "total": total,
            "line": chosen.get("line", ""),
            "track": chosen.get("track", ""),
            "page": page,
            "previous_url": at(page - 1) if page > 1 else None,
            "next_url": at(page + 1) if page * PAGE_SIZE < total else None,
        }
        return render(request, "runs.html", context)


@router.get("/runs/{reference}")
def run(
    request: Request, reference: str, user: Annotated[Principal, requires("viewer", page_user)]
) -> Response:
    with session_scope(state(request).engine, read_only=True) as session:
        found = run_of(session, reference)
        spans, span_wires = session.execute(
            select(func.count(distinct(SpanMeasurement.span)), func.count()).where(
                SpanMeasurement.processing_id == found.processing_id
            )
        ).one()
        processings = [
            (p, alignment_summary(p), p.id == found.processing_id) for p in found.processings
        ]
        context = {
            "run": found,
            "spans": spans,
            "span_wires": span_wires,
            "processings": processings,
            "alignment": alignment_summary(found.processing) if found.processing else "",
            "report": RUN_REPORTER in state(request).registry.reporters(),
        }
        return render(request, "run.html", context)


@router.get("/runs/{reference}/report")
def run_report(
    request: Request, reference: str, user: Annotated[Principal, requires("viewer", page_user)]
) -> Response:
    """The run report's HTML, written into a temporary folder by the run reporter (its line-scan
    crops are in the page itself)."""
    shared = state(request)
    reporter = shared.registry.reporters().get(RUN_REPORTER)
    if reporter is None:
        raise NotFound(f"no {RUN_REPORTER!r} reporter is registered (catenary plugins says why)")
    with session_scope(shared.engine, read_only=True) as session:
        run_id = run_of(session, reference).id
    report = report_request(shared.settings, shared.registry, runs=(str(run_id),))
    with tempfile.TemporaryDirectory(prefix="catenary-report-") as folder:
        output = Path(folder) / f"run-{run_id}.html"
        with shared.registry.boundary("reporter", RUN_REPORTER):
            written = reporter.write(report, output)
        return HTMLResponse(written.read_text(encoding="utf-8"))
