"""The API's samples: ``GET /samples`` gives a run's full-resolution samples of a chainage
range from its samples file in the store, as the ``samples`` export (FORMATS.md): a page of
JSON with the ``next`` page's address, or the whole range streamed as NDJSON or CSV. Only the
file's row groups whose chainage statistics reach the range are read."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterator
from typing import Annotated, Any, Literal

import pyarrow as pa
from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse
from pydantic import BaseModel
from starlette.responses import Response

from catenary.measurement.samples import (
    EXPORT_COLUMNS,
    StoredSamples,
    run_samples,
    samples_in_range,
)
from catenary.storage.database import session_scope
from catenary.storage.spans import wire_positions_of
from catenary.web.api.runs import errors, run_of
from catenary.web.api.spans import chainage_query, check_range
from catenary.web.app import state
from catenary.web.auth import Principal, requires

__all__ = ["SampleOut", "SamplePageOut", "router"]

router = APIRouter(tags=["samples"], responses=errors())

MAX_SAMPLES = 10_000
"""The most samples one JSON page holds."""
STREAM_BLOCK = 16_384
"""Samples read per step of a stream."""


class SampleOut(BaseModel):
    """One scan and contact wire (the ``samples`` export; None: not measured)."""

    scan: int
    position_m: float
    chainage_m: float
    wire: int
    height_mm: float | None
    stagger_mm: float | None
    wear_width_mm: float | None
    residual_thickness_mm: float | None
    wire_position: int | None
    selection_uncertain: bool
    cameras: int


class SamplePageOut(BaseModel):
    """A page of samples of run ``run_id`` in file order (scan, wire); ``next``: the next
    page's address (None: the last)."""

    run_id: int
    run_uuid: str
    from_m: float
    to_m: float
    next: str | None
    samples: list[SampleOut]


def _records(table: pa.Table) -> list[dict[str, Any]]:
    """The rows of a samples table, NaN as None (JSON has no NaN)."""
    return [
        {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in row.items()}
        for row in table.to_pylist()
    ]


def _stream(
    source: StoredSamples,
    positions: dict[tuple[int, int], int],
    from_m: float,
    to_m: float,
    media: str,
) -> Iterator[bytes]:
    """The samples of the range, block by block, as NDJSON or CSV (with a header)."""
    if media == "csv":
        yield (",".join(EXPORT_COLUMNS) + "\r\n").encode()
    after: int | None = -1
    while after is not None:
        page = samples_in_range(source, positions, from_m, to_m, after=after, limit=STREAM_BLOCK)
        rows = _records(page.table)
        if media == "csv":
            text = io.StringIO()
            writer = csv.writer(text)
            writer.writerows(["" if r[c] is None else r[c] for c in EXPORT_COLUMNS] for r in rows)
            yield text.getvalue().encode()
        else:
            yield "".join(json.dumps(r) + "\n" for r in rows).encode()
        after = page.next_after


@router.get(
    "/samples",
    response_model=SamplePageOut,
    responses={
        200: {"content": {"application/x-ndjson": {}, "text/csv": {}}},
        **errors({400: "The run has no samples file.", 404: "No such run."}),
    },
)
def samples(
    request: Request,
    user: Annotated[Principal, requires("viewer")],
    run: Annotated[str, Query(max_length=64, description="A run id, UUID, prefix or 'latest'.")],
    from_m: Annotated[float, chainage_query("From this chainage [m].")],
    to_m: Annotated[float, chainage_query("To this chainage [m].")],
    limit: Annotated[int, Query(ge=1, le=MAX_SAMPLES, description="Samples per page.")] = 1000,
    after: Annotated[
        int, Query(ge=-1, description="The cursor: the previous page's next gives it.")
    ] = -1,
    format: Annotated[
        Literal["json", "ndjson", "csv"],
        Query(description="json: a page; ndjson or csv: the whole range, streamed."),
    ] = "json",
) -> SamplePageOut | Response:
    """The samples of a run's latest processing from ``from_m`` to ``to_m`` [m]."""
    check_range(from_m, to_m)
    web = state(request)
    with session_scope(web.engine, read_only=True) as session:
        found = run_of(session, run)
        run_id, run_uuid = found.id, found.uuid
        source = run_samples(web.store, found)
        positions = wire_positions_of(session, found.processing_id)
    if format != "json":
        media = "text/csv" if format == "csv" else "application/x-ndjson"
        return StreamingResponse(_stream(source, positions, from_m, to_m, format), media_type=media)
    page = samples_in_range(source, positions, from_m, to_m, after=after, limit=limit)
    following = (
        None
        if page.next_after is None
        else str(request.url.include_query_params(after=page.next_after))
    )
    return SamplePageOut(
        run_id=run_id,
        run_uuid=run_uuid,
        from_m=from_m,
        to_m=to_m,
        next=following,
        samples=[SampleOut(**r) for r in _records(page.table)],
    )
