"""The worn face's width of each matched point from every confirming camera, and the lit chord
of the points located by their silhouettes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from catenary.arrays import FloatArray, IntArray, row_median
from catenary_linescan.calibration import ResolutionTable
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.processor.features import FACE_RESOLVED_PX

from .candidates import Candidates
from .geometry import _gather, _Geometry, _line_coefficients, _undistort
from .triangulate import Matches


@dataclass(frozen=True, eq=False)
class FaceWidths:
    """The worn face's width of each match, per camera and combined.

    Attributes
    ----------
    per_camera_mm : ndarray, shape (m, C)
        Width from each confirming camera's face edges and its model [mm]; NaN where the
        camera did not see the face.
    table_ratio : ndarray, shape (m, C)
        That width over the look-up table's (``ResolutionTable.at × width_px``) [-]: the
        cross-check of the camera model against the calibration targets.
    width_mm : ndarray, shape (m,)
        Combined width [mm]: median of the cameras, then the mean weighted by each camera's
        precision (``1 / resolution²``) over the cameras within ``tolerance`` of the median,
        when two cameras at least agree. Only the cameras that resolve both face edges where
        two of those agree: a dark silhouette's face edge closer than ``FACE_RESOLVED_PX``
        to its silhouette is one blurred step with it, and lies outward of the face's edge.
        0.0 when no confirming camera saw a face (a new wire, or a face narrower than the
        features resolve, about two pixels: 0.6 mm, which leaves the residual thickness
        within 0.01 mm of the new wire's); NaN when faces were seen but fewer than two
        cameras agree (not measured).
    spread_mm : ndarray, shape (m,)
        Largest difference of an agreeing camera from the combined width [mm].
    cameras : ndarray of int, shape (m,)
        Cameras that agreed (used in ``width_mm``).
    """

    per_camera_mm: FloatArray
    table_ratio: FloatArray
    width_mm: FloatArray
    spread_mm: FloatArray
    cameras: IntArray


def _ray_on_plane(
    camera: LineScanCamera,
    u_px: FloatArray,
    x0: FloatArray,
    z0: FloatArray,
    dx: FloatArray,
    dz: FloatArray,
) -> FloatArray:
    """Parameter ``t`` [mm] where the ray of ``u_px`` meets the line ``(x0, z0) + t (dx, dz)``.

    The ray of ideal coordinate ``u`` is the line ``p x + q z = k`` (equation 10). ``u_px``
    is ``(..., r)``, the line's arrays ``(r,)``; ``t`` has ``u_px``'s shape.
    """
    p, q, k = _line_coefficients(camera.matrix, _undistort(camera, u_px))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (k - p * x0 - q * z0) / (p * dx + q * dz)
    return np.asarray(t, dtype=np.float64)


def face_widths_mm(
    cameras: Sequence[LineScanCamera],
    tables: Sequence[ResolutionTable],
    candidates: Candidates,
    matches: Matches,
    roll_rad: FloatArray | None = None,
    *,
    tolerance_mm: float = 0.25,
    max_width_mm: float = 14.8,
) -> FaceWidths:
    """Width of each match's worn face from every confirming camera, and combined.

    Parameters
    ----------
    cameras : sequence of LineScanCamera, length C
    tables : sequence of ResolutionTable, length C
        Each camera's look-up table (the cross-check).
    candidates : Candidates
        The candidates the matches refer to.
    matches : Matches
        The matched points (``x_mm``, ``z_mm``: the face's centre).
    roll_rad : ndarray, shape (n,), optional
        The car body's roll per scan of the block [rad] (positive: left side up): the face,
        horizontal in the track frame, runs along ``(cos φ, sin φ)`` in the roof frame. None:
        no roll.
    tolerance_mm : float
        Cameras further than this from the median width are left out of the mean [mm].
    max_width_mm : float
        Widest face a contact wire can have (its width) [mm]: a wider "face" is a fitting's
        (a clamp's flat underside), and that camera's width is left out.

    Returns
    -------
    FaceWidths
    """
    m = matches.count
    n_cameras = len(cameras)
    left, right = _gather(
        matches.scan, matches.slot, candidates.face_left_px, candidates.face_right_px
    )
    phi = np.zeros(m) if roll_rad is None else np.asarray(roll_rad, np.float64)[matches.scan]
    dx, dz = np.cos(phi), np.sin(phi)
    per_camera = np.full((m, n_cameras), np.nan)
    faces = np.zeros(m, dtype=np.int64)  # cameras that saw a face, too wide or not
    ratio = np.full((m, n_cameras), np.nan)
    resolution = np.full((m, n_cameras), np.nan)
    x, z = matches.x_mm, matches.z_mm
    for c, (camera, table) in enumerate(zip(cameras, tables, strict=True)):
        geometry = _Geometry.of(camera)
        seen = np.isfinite(left[:, c]) & np.isfinite(right[:, c]) & np.isfinite(x)
        if not np.any(seen):
            continue
        rows = np.flatnonzero(seen)
        x_c, z_c = x[rows], z[rows]
        edges = np.stack([left[rows, c], right[rows, c]])  # (2, r): both edges in one call
        t_left, t_right = _ray_on_plane(camera, edges, x_c, z_c, dx[rows], dz[rows])
        width = np.abs(t_right - t_left)
        per_camera[rows, c] = np.where(width <= max_width_mm, width, np.nan)
        faces[rows] += 1
        width_px = np.abs(edges[1] - edges[0])
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio[rows, c] = width / (table.at(x_c, z_c) * width_px)
        _, du_dx, _ = geometry.project(x_c, z_c)
        resolution[rows, c] = 1.0 / np.abs(du_dx)  # ideal model: enough for a weight
    # a dark silhouette's face edge closer to its silhouette than the features can part them
    # is that merged step, outward by more than its distance from the silhouette (features
    # module docstring; a bright face's, on a darker sky, is off by far less)
    sil_left, sil_right, polarity = _gather(
        matches.scan,
        matches.slot,
        candidates.left_px,
        candidates.right_px,
        candidates.polarity.astype(np.float64),
    )
    merged = np.fmin(left - sil_left, sil_right - right) < FACE_RESOLVED_PX
    resolved = ~(merged & (polarity < 0.0))
    clear = _combine(np.where(resolved, per_camera, np.nan), resolution, tolerance_mm)
    every = _combine(per_camera, resolution, tolerance_mm)
    use_clear = clear[1] >= 2
    combined, agreeing, spread = (
        np.where(use_clear, a, b) for a, b in zip(clear, every, strict=True)
    )
    # two cameras at least must agree on a face; none seeing one is a face below resolution
    combined = np.where(agreeing >= 2, combined, np.where(faces == 0, 0.0, np.nan))
    combined = np.where(np.isfinite(x), combined, np.nan)
    spread = np.where(agreeing >= 2, spread, np.nan)
    return FaceWidths(
        per_camera_mm=per_camera,
        table_ratio=ratio,
        width_mm=combined,
        spread_mm=spread,
        cameras=agreeing.astype(np.int64),
    )


def _combine(
    per_camera: FloatArray, resolution: FloatArray, tolerance_mm: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Each row's cameras ``(m, C)`` [mm] (NaN: none) combined: the mean weighted by
    precision (``1 / resolution²``, ``resolution`` ``(m, C)`` [mm/px]) over the cameras within
    ``tolerance_mm`` of the median; with how many those are and their largest difference
    from the mean [mm], each ``(m,)``."""
    median = row_median(per_camera)
    with np.errstate(invalid="ignore", divide="ignore"):
        agree = np.abs(per_camera - median[:, np.newaxis]) <= tolerance_mm
        weight = np.where(agree, 1.0 / resolution**2, 0.0)
        combined = (weight * np.nan_to_num(per_camera)).sum(axis=1) / weight.sum(axis=1)
        deviation = np.where(agree, np.abs(per_camera - combined[:, np.newaxis]), 0.0)
    return combined, agree.sum(axis=1).astype(np.float64), deviation.max(axis=1, initial=0.0)


def lit_chord_mm(
    cameras: Sequence[LineScanCamera],
    candidates: Candidates,
    matches: Matches,
    roll_rad: FloatArray | None = None,
) -> FloatArray:
    """Width of the lit silhouette of each match located by its silhouettes (``from_face``
    false): the silhouette's width in every camera that saw it brighter than the sky
    (polarity +1: a wire lit from below at night) over the camera model's resolution along
    the face's plane at the point (``(cos φ, sin φ)`` with the body's roll), median of those
    cameras.

    A round wire lit from below shows its bottom: the lit part's ends are two points of its
    circle at one height, and the middles of its silhouettes triangulate to the middle of
    that chord, not to the axis (:func:`..stereo.contact_from_axis`). A point that a camera
    saw the outline of on one side (``Candidates.outline_side``) was triangulated to the axis:
    no chord.

    Returns
    -------
    ndarray, shape (m,)
        The chord [mm]; NaN where no camera saw the match bright, or it has a face.
    """
    chord = np.full(matches.count, np.nan)
    rows = np.flatnonzero(~matches.from_face)
    if rows.shape[0] == 0:
        return chord
    bright = candidates.polarity > 0
    left, right, outline = _gather(
        matches.scan[rows],
        matches.slot[rows],
        np.where(bright, candidates.left_px, np.nan),
        np.where(bright, candidates.right_px, np.nan),
        np.abs(candidates.outline_side).astype(np.float64),
    )
    phi = np.zeros(rows.shape[0]) if roll_rad is None else roll_rad[matches.scan[rows]]
    x, z = matches.x_mm[rows], matches.z_mm[rows]
    per_camera = np.full(left.shape, np.nan)
    for c, camera in enumerate(cameras):  # a loop per camera, not per point
        _, du_dx, du_dz = _Geometry.of(camera).project(x, z)
        along = np.abs(du_dx * np.cos(phi) + du_dz * np.sin(phi))  # px per mm
        with np.errstate(invalid="ignore", divide="ignore"):
            per_camera[:, c] = (right[:, c] - left[:, c]) / along
    chord[rows] = np.where(np.nansum(outline, axis=1) > 0, np.nan, row_median(per_camera))
    return chord
