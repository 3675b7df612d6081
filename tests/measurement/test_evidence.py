"""Image evidence: each span's thinnest sample, its crop of every camera, in the store."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image
from sqlalchemy import create_engine, select
from sqlalchemy.orm import Session

from catenary.config import load_settings
from catenary.domain import CameraLines, ScanBlock, VehicleSamples
from catenary.measurement.evidence import (
    HALF_LENGTH_M,
    HALF_WIDTH_PX,
    NARROW_WIDTH_PX,
    SEPARATOR_PX,
    EvidencePoint,
    SpanMinima,
    crop_image,
    cut_evidence,
    evidence_key,
)
from catenary.storage.models import Run
from catenary.storage.store import open_store


def test_span_minima_keep_each_spans_and_wires_least_value_over_blocks() -> None:
    minima = SpanMinima()
    minima.add(
        np.array([0, 0, 1, 0]), np.array([0, 1, 0, 0]), np.array([11.0, 10.0, np.nan, 10.5]),
        np.array([5, 6, 7, 8]), np.array([1.0, 2.0, 3.0, 4.0]), np.array([9.0] * 4),
    )  # fmt: skip
    minima.add(
        np.array([0, 1, 1]), np.array([0, 0, 0]), np.array([10.7, 12.0, 11.9]),
        np.array([20, 21, 22]), np.array([5.0, 6.0, 7.0]), np.array([8.0] * 3),
    )  # fmt: skip
    assert minima.points() == [
        EvidencePoint(span=0, wire=1, scan=6, x_roof_mm=2.0, z_roof_mm=9.0),
        EvidencePoint(span=0, wire=0, scan=8, x_roof_mm=4.0, z_roof_mm=9.0),
        EvidencePoint(span=1, wire=0, scan=22, x_roof_mm=7.0, z_roof_mm=8.0),
    ]


def _block(
    lines: dict[str, np.ndarray], first: int = 0, metres_per_scan: float = 0.05
) -> ScanBlock:
    n = next(iter(lines.values())).shape[0]
    zeros = np.zeros(n)
    return ScanBlock(
        first_scan=first,
        position_m=(first + np.arange(n)) * metres_per_scan,
        time_s=zeros,
        cameras={name: CameraLines(v, bit_depth=12, offset_px=100) for name, v in lines.items()},
        vehicle=VehicleSamples(zeros, zeros, zeros, zeros),
    )


def test_a_crop_holds_each_camera_around_the_point_side_by_side() -> None:
    lines = np.zeros((40, 4096), np.uint16)
    lines[:, 1000 - 100] = 4000  # sensor pixel 1000: line pixel 900 (offset 100)
    lines[:, 4095] = 3000
    block = _block({"a": lines, "b": lines})
    image = crop_image(block, slice(5, 25), {"a": 1000.0, "b": 4150.0}, ["a", "b"])
    width = 2 * HALF_WIDTH_PX + 1
    assert image.shape == (20, 2 * width + SEPARATOR_PX) and image.dtype == np.uint8
    a, b = image[:, :width], image[:, width + SEPARATOR_PX :]
    assert np.all(a[:, HALF_WIDTH_PX] == 255) and np.all(np.delete(a, HALF_WIDTH_PX, 1) == 0)
    # camera b's point lies past its line's end: its last pixel, then black
    last = 4095 + 100 - (4150 - HALF_WIDTH_PX)
    assert np.all(b[:, last] == 255) and np.all(b[:, last + 1 :] == 0)
    # without columns: the whole line, averaged down
    whole = crop_image(block, slice(0, 40), None, ["a"])
    assert whole.shape == (40, NARROW_WIDTH_PX)


def test_cut_evidence_takes_a_metre_around_each_point() -> None:
    lines = np.arange(400 * 8, dtype=np.uint16).reshape(400, 8)
    read: list[tuple[int, int]] = []

    def blocks(start: int, stop: int) -> ScanBlock:
        read.append((start, stop))
        return _block({"a": lines[start:stop]}, first=start, metres_per_scan=0.02)

    points = [EvidencePoint(0, 0, 200, 0.0, 0.0), EvidencePoint(1, 0, 3, 0.0, 0.0)]
    crops = list(cut_evidence(blocks, 400, 0.02, points, None, ["a"]))
    assert [p for p, _ in crops] == points
    rows = 2 * round(HALF_LENGTH_M / 0.02) + 1
    assert crops[0][1].shape[0] == rows  # 25 scans either side
    assert crops[1][1].shape[0] == 3 + 1 + round(HALF_LENGTH_M / 0.02)  # the run's start
    assert all(stop - start <= 2 * 39 + 1 for start, stop in read)  # no more than needed


@pytest.mark.slow
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_process_stores_a_crop_of_every_span_with_the_wire_at_its_centre(
    small_run: Any, database_url: str, isolated_environment: Path
) -> None:
    from click.testing import CliRunner

    from catenary.cli import cli

    result = CliRunner().invoke(cli, ["--db", database_url, "db", "upgrade"])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(cli, small_run.process_args(database_url))
    assert result.exit_code == 0, result.output
    store = open_store(load_settings())
    with Session(create_engine(database_url)) as session:
        (run,) = session.scalars(select(Run))
        assert run.processing is not None
        made, rows = run.processing.uuid, list(run.span_measurements)
    keys = {evidence_key(made, s.span, s.wire) for s in rows}
    at_masts = {evidence_key(made, s.span, s.wire, "mast") for s in rows}
    stored = set(store.keys("evidence"))
    # each span's thinnest point; and its first mast where the wire ran within half a metre
    assert keys and keys <= stored and stored - keys <= at_masts and stored - keys
    assert f"evidence   {len(stored)} image crops in " in result.output
    keys = stored
    width = 2 * HALF_WIDTH_PX + 1
    for key in keys:
        with store.open_input(key) as handle:
            data = handle.read()
        assert len(data) < 64_000  # kept small
        image = np.asarray(Image.open(io.BytesIO(data)))
        cameras = (image.shape[1] + SEPARATOR_PX) // (width + SEPARATOR_PX)
        assert cameras == 4 and image.shape[0] > 10
        for k in range(cameras):
            crop = image[:, k * (width + SEPARATOR_PX) : k * (width + SEPARATOR_PX) + width]
            # the lit wire (night) is the crop's brightest column, within a few pixels of its
            # middle: the processor's point projected into each camera
            profile = np.median(crop, axis=0)
            assert abs(int(np.argmax(profile)) - HALF_WIDTH_PX) <= 12, key
