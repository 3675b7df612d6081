"""Image evidence: the line-scan images around a run's worst points, kept small in the store.

For each span and wire, ``process`` finds the sample with the least residual thickness, and
the one nearest the span's first mast within ``HALF_LENGTH_M`` (where the geometry at a mast is
measured), over the trusted samples (``SpanMinima``), and, while the run file is at hand, cuts
a crop of every camera's lines around each: the scans within ``HALF_LENGTH_M`` of it along the
track and, across the line, ``HALF_WIDTH_PX`` pixels either side of where each camera sees the point
(the processor tells: ``ImageLocator``; without it, the whole line narrowed to
``NARROW_WIDTH_PX`` by averaging). The cameras' crops lie side by side in one 8-bit greyscale
PNG (scans downwards, in run order; a grey bar between cameras; each camera's levels
stretched to the full range, so that a dark night scene shows), stored under
``evidence/PROCESSING/span-S-wire-W.png`` and ``...-mast.png`` (``evidence_key``): a run
report and every alert on that span (a geometry alert: the mast's) read it, wherever the run
was processed (``catenary push`` sends it along).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

from catenary.arrays import FloatArray
from catenary.domain import ScanBlock

if TYPE_CHECKING:
    from catenary.measurement.runfile import RunFile

__all__ = [
    "EVIDENCE_PREFIX",
    "POINTS",
    "Cut",
    "EvidencePoint",
    "SpanMinima",
    "crop_image",
    "cut_evidence",
    "cut_pngs",
    "evidence_key",
    "evidence_prefix",
    "png_bytes",
    "point_columns",
]

EVIDENCE_PREFIX = "evidence"
HALF_LENGTH_M = 0.5
"""Track either side of the point a crop holds [m] (a metre around it)."""
HALF_WIDTH_PX = 96
"""Pixels either side of the point's column a crop holds, per camera."""
NARROW_WIDTH_PX = 1024
"""Without a locator, a camera's whole line is averaged down to at most this many pixels."""
MAX_HALF_SCANS = 4096
"""At most this many scans either side of the point (a vehicle that crawled)."""
SEPARATOR_PX = 4
SEPARATOR_GREY = 128
STRETCH_PERCENT = 0.5
"""Each camera's crop is stretched to full 8-bit range between these percentiles [%]."""

Locator = Callable[[FloatArray, FloatArray], Mapping[str, FloatArray]]
"""Roof-frame points (x, z) [mm] -> each camera's sensor pixel of them (``ImageLocator``)."""


def evidence_prefix(processing_uuid: str) -> str:
    """The folder of a processing's evidence in the store."""
    return f"{EVIDENCE_PREFIX}/{processing_uuid}"


POINTS = ("minimum", "mast")
"""Where a span's crops are: its thinnest point, and its first mast."""


def evidence_key(processing_uuid: str, span: int, wire: int, point: str = "minimum") -> str:
    """The store key of the crop of ``wire`` at span ``span``'s (its stored number) thinnest
    point, or at its first mast (``point``: one of ``POINTS``)."""
    if point not in POINTS:
        raise ValueError(f"no crop point {point!r} (one of {', '.join(POINTS)})")
    at = "" if point == "minimum" else f"-{point}"
    return f"{evidence_prefix(processing_uuid)}/span-{span}-wire-{wire}{at}.png"


@dataclass(frozen=True)
class EvidencePoint:
    """A point to cut a crop at: span (layout index), wire, scan and roof-frame position."""

    span: int
    wire: int
    scan: int
    x_roof_mm: float
    z_roof_mm: float


class SpanMinima:
    """Per span and wire, the sample with the least value (a residual thickness, a distance
    to a mast), over blocks."""

    def __init__(self) -> None:
        self._best = np.zeros(0, dtype=_ROW)

    def add(
        self,
        span: np.ndarray,
        wire: np.ndarray,
        value: FloatArray,
        scan: np.ndarray,
        x_roof_mm: FloatArray,
        z_roof_mm: FloatArray,
    ) -> None:
        """Samples, each ``(m,)`` (NaN values are left out)."""
        keep = np.isfinite(value)
        rows = np.zeros(int(np.count_nonzero(keep)), dtype=_ROW)
        for name, values in (("span", span), ("wire", wire), ("value", value),
                             ("scan", scan), ("x", x_roof_mm), ("z", z_roof_mm)):  # fmt: skip
            rows[name] = np.asarray(values)[keep]
        both = np.concatenate([self._best, rows])
        order = np.lexsort((both["scan"], both["value"], both["wire"], both["span"]))
        both = both[order]
        first = np.ones(both.shape[0], dtype=bool)
        first[1:] = (both["span"][1:] != both["span"][:-1]) | (
            both["wire"][1:] != both["wire"][:-1]
        )
        self._best = both[first]

    def points(self) -> list[EvidencePoint]:
        """The minima, by scan."""
        best = self._best[np.argsort(self._best["scan"], kind="stable")]
        return [
            EvidencePoint(
                int(r["span"]), int(r["wire"]), int(r["scan"]), float(r["x"]), float(r["z"])
            )
            for r in best
        ]


_ROW = np.dtype(
    [("span", np.int64), ("wire", np.int64), ("value", np.float64), ("scan", np.int64),
     ("x", np.float64), ("z", np.float64)]
)  # fmt: skip


def _stretched(part: np.ndarray) -> np.ndarray:
    """A camera's crop ``[n, w]`` as 8-bit grey, its levels stretched from its
    ``STRETCH_PERCENT`` darkest to its brightest (a night scene and a sunlit one alike)."""
    low, high = np.percentile(part, [STRETCH_PERCENT, 100.0 - STRETCH_PERCENT])
    scale = 255.0 / (high - low) if high > low else 0.0
    return np.asarray(np.clip((part - low) * scale, 0.0, 255.0).round(), dtype=np.uint8)


def _narrowed(lines: np.ndarray) -> np.ndarray:
    """A whole line ``[n, w]`` averaged down to at most ``NARROW_WIDTH_PX`` pixels."""
    factor = max(1, math.ceil(lines.shape[1] / NARROW_WIDTH_PX))
    width = lines.shape[1] // factor * factor
    return np.asarray(lines[:, :width].reshape(lines.shape[0], -1, factor).mean(axis=2))


def crop_image(
    block: ScanBlock,
    rows: slice,
    columns_px: Mapping[str, float] | None,
    cameras: Sequence[str],
) -> np.ndarray:
    """The crop of ``rows`` of the block's scans, the cameras side by side, ``[n, width]``
    uint8. ``columns_px``: each camera's sensor pixel of the point (None: whole lines,
    narrowed). Pixels beyond a camera's line are black."""
    parts = []
    for name in cameras:
        camera = block.cameras[name]
        lines = np.asarray(camera.lines[rows], dtype=np.float64)
        column = None if columns_px is None else columns_px.get(name, math.nan)
        if column is None or not math.isfinite(column):
            part = _narrowed(lines)
        else:
            centre = round(column) - camera.offset_px
            part = np.zeros((lines.shape[0], 2 * HALF_WIDTH_PX + 1))
            low, high = centre - HALF_WIDTH_PX, centre + HALF_WIDTH_PX + 1
            inside = slice(max(low, 0), min(high, lines.shape[1]))
            if inside.start < inside.stop:
                part[:, inside.start - low : inside.stop - low] = lines[:, inside]
        parts.append(_stretched(part))
        parts.append(np.full((lines.shape[0], SEPARATOR_PX), SEPARATOR_GREY, np.uint8))
    return np.concatenate(parts[:-1], axis=1)


def png_bytes(image: np.ndarray) -> bytes:
    """An 8-bit greyscale image ``[rows, columns]`` as PNG."""
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image), mode="L").save(out, format="PNG")
    return out.getvalue()


def point_columns(points: Sequence[EvidencePoint], locate: Locator) -> list[Mapping[str, float]]:
    """Each point's sensor pixel in each camera (``locate`` called once for them all)."""
    if not points:
        return []
    found = locate(np.array([p.x_roof_mm for p in points]), np.array([p.z_roof_mm for p in points]))
    return [{name: float(found[name][k]) for name in found} for k in range(len(points))]


def cut_evidence(
    blocks: Callable[[int, int], ScanBlock],
    scans: int,
    metres_per_scan: float,
    points: Sequence[EvidencePoint],
    columns: Sequence[Mapping[str, float]] | None,
    cameras: Sequence[str],
) -> Iterator[tuple[EvidencePoint, np.ndarray]]:
    """Each point's crop (``crop_image``, at its ``columns``: ``point_columns``; None: whole
    lines): ``blocks(start, stop)`` reads scans ``start:stop`` of the run (``scans`` of them,
    about ``metres_per_scan`` apart)."""
    if not points:
        return
    spacing = metres_per_scan if metres_per_scan > 0 else HALF_LENGTH_M
    reach = min(MAX_HALF_SCANS, math.ceil(1.5 * HALF_LENGTH_M / spacing) + 1)
    located: Sequence[Mapping[str, float] | None] = columns or [None] * len(points)
    for point, column in zip(points, located, strict=True):
        start, stop = max(point.scan - reach, 0), min(point.scan + reach + 1, scans)
        block = blocks(start, stop)
        at = block.position_m[point.scan - start]
        near = np.flatnonzero(np.abs(block.position_m - at) <= HALF_LENGTH_M)
        rows = slice(int(near[0]), int(near[-1]) + 1)
        yield point, crop_image(block, rows, column, cameras)


@dataclass(frozen=True)
class Cut:
    """Crops to cut from a run file: ``cut_evidence``'s arguments but its blocks (picklable,
    for a worker process that has the run file open)."""

    scans: int
    metres_per_scan: float
    points: Sequence[EvidencePoint]
    columns: Sequence[Mapping[str, float]] | None
    cameras: Sequence[str]


def cut_pngs(run: RunFile, cut: Cut) -> list[bytes]:
    """The PNG (``png_bytes``) of each of ``cut``'s crops from ``run``, in its points' order."""
    crops = cut_evidence(
        run.image_block, cut.scans, cut.metres_per_scan, cut.points, cut.columns, cut.cameras
    )
    return [png_bytes(image) for _, image in crops]
