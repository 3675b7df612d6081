"""The matching's input: each camera's profile features padded to ``(n, C, K)`` arrays (step 1
of the package docstring), and the cameras' centre uncertainties."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import FloatArray, IntArray


class FeatureTable(Protocol):
    """One camera's profile features for a block of scans, flattened: fields shape (m,).

    ``scan`` is the scan's index within the block; pixel positions follow FORMATS.md.
    ``polarity`` is +1 for a candidate brighter than its background, -1 darker, 0 unknown;
    ``outline_side`` -1 or +1 where only the left or the right boundary is the wire's outline
    (``LineFeatures.outline_side``), else 0.
    """

    @property
    def scan(self) -> NDArray[np.integer]: ...
    @property
    def centre_px(self) -> FloatArray: ...
    @property
    def left_px(self) -> FloatArray: ...
    @property
    def right_px(self) -> FloatArray: ...
    @property
    def face_left_px(self) -> FloatArray: ...
    @property
    def face_right_px(self) -> FloatArray: ...
    @property
    def contrast(self) -> FloatArray: ...
    @property
    def polarity(self) -> NDArray[np.integer]: ...
    @property
    def outline_side(self) -> NDArray[np.integer]: ...


@dataclass(frozen=True, eq=False)
class Candidates:
    """Candidates padded per scan and camera: every field ``(n, C, K)``; NaN / -1 padding.

    ``detection`` is each candidate's row in its camera's flat feature table (-1: padding).
    """

    centre_px: FloatArray
    left_px: FloatArray
    right_px: FloatArray
    face_left_px: FloatArray
    face_right_px: FloatArray
    contrast: FloatArray
    polarity: NDArray[np.int8]
    outline_side: NDArray[np.int8]
    detection: IntArray

    @property
    def shape(self) -> tuple[int, int, int]:
        n, c, k = self.centre_px.shape
        return int(n), int(c), int(k)


def pad_candidates(
    features: Sequence[FeatureTable],
    scans: int,
    max_candidates: int = 24,
    offsets_px: Sequence[int] = (),
) -> Candidates:
    """Gather flat per-camera features into ``(n, C, K)`` arrays in camera pixels.

    Parameters
    ----------
    features : sequence of FeatureTable, length C
        One flat table per camera, in the rig's camera order.
    scans : int
        Scans in the block (``n``); ``scan`` values must lie in ``[0, n)``.
    max_candidates : int
        Cap on ``K``; in a scan with more candidates the weakest (lowest contrast) are dropped.
    offsets_px : sequence of int, length C (or empty: all 0)
        Each camera's region of interest: line pixel ``i`` is camera pixel
        ``offsets_px[c] + i``, added to every position.

    Returns
    -------
    Candidates
        ``K`` is the largest count of any scan and camera (at most ``max_candidates``, at
        least 1), candidates of a scan in order of position along the line.
    """
    counts = []
    for table in features:
        scan = np.asarray(table.scan, dtype=np.int64)
        counts.append(np.bincount(scan, minlength=scans)[:scans] if scan.size else np.zeros(1))
    k = int(max(1, min(max_candidates, max(int(np.max(c, initial=0)) for c in counts))))
    n_cameras = len(features)
    shape = (scans, n_cameras, k)
    out = {
        name: np.full(shape, np.nan)
        for name in ("centre_px", "left_px", "right_px", "face_left_px", "face_right_px")
    }
    contrast = np.full(shape, np.nan)
    polarity = np.zeros(shape, dtype=np.int8)
    outline_side = np.zeros(shape, dtype=np.int8)
    detection = np.full(shape, -1, dtype=np.int64)
    for column, table in enumerate(features):
        scan = np.asarray(table.scan, dtype=np.int64)
        if scan.size == 0:
            continue
        strength = np.nan_to_num(np.asarray(table.contrast, dtype=np.float64), nan=0.0)
        centre = np.asarray(table.centre_px, dtype=np.float64)
        if int(counts[column].max()) <= k and bool(np.all(scan[1:] >= scan[:-1])):
            # the usual case: in scan order and none over the cap
            rows = np.arange(scan.shape[0])
            scan_kept = scan
        else:
            # strongest first within a scan, to rank and cap, then by position along the line
            order = np.lexsort((-np.abs(strength), scan))
            sorted_scan = scan[order]
            rank = np.arange(order.shape[0]) - np.searchsorted(sorted_scan, sorted_scan)
            rows = order[rank < k]
            rows = rows[np.lexsort((centre[rows], scan[rows]))]
            scan_kept = scan[rows]
        slot = np.arange(rows.shape[0]) - np.searchsorted(scan_kept, scan_kept, side="left")
        offset = float(offsets_px[column]) if offsets_px else 0.0
        for name, values in out.items():
            line_px = np.asarray(getattr(table, name), np.float64)[rows]
            values[scan_kept, column, slot] = line_px + offset
        contrast[scan_kept, column, slot] = strength[rows]
        polarity[scan_kept, column, slot] = np.asarray(table.polarity)[rows]
        outline_side[scan_kept, column, slot] = np.asarray(table.outline_side)[rows]
        detection[scan_kept, column, slot] = rows
    return Candidates(
        centre_px=out["centre_px"],
        left_px=out["left_px"],
        right_px=out["right_px"],
        face_left_px=out["face_left_px"],
        face_right_px=out["face_right_px"],
        contrast=contrast,
        polarity=polarity,
        outline_side=outline_side,
        detection=detection,
    )


def camera_sigmas_px(reprojection_rms_px: Sequence[float], feature_sigma_px: float) -> FloatArray:
    """Per-camera standard deviation of a candidate's centre [px], shape (C,).

    ``sqrt(rms² + σ_feature²)``; an unknown (NaN) calibration RMS counts as 0.5 px.
    """
    rms = np.asarray(reprojection_rms_px, dtype=np.float64)
    rms = np.where(np.isfinite(rms), rms, 0.5)
    return np.asarray(np.hypot(rms, feature_sigma_px), dtype=np.float64)
