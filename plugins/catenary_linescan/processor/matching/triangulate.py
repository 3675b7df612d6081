"""Step 5 of the package docstring: each accepted point triangulated from all its cameras."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import BoolArray, FloatArray, IntArray, row_median
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.triangulation import TriangulationResult, triangulate

from .candidates import Candidates
from .config import MatchConfig
from .geometry import _WHOLE, _gather, _Geometry, _outline_axis, _pinhole, _undistort


@dataclass(frozen=True, eq=False)
class Matches:
    """Points confirmed by the matching, ``m`` of them (one per wire and scan).

    Attributes
    ----------
    scan : ndarray of int, shape (m,)
        Scan index within the block.
    slot : ndarray of int, shape (m, C)
        The candidate (index along ``K`` of :class:`Candidates`) each camera contributed; -1
        where the camera did not confirm the point.
    x_mm, z_mm : ndarray, shape (m,)
        Roof-frame position [mm] from all confirming cameras: the worn face's centre where two
        cameras saw the face (``from_face``), else the wire's axis (the middles of its
        silhouettes: a camera's face centre is never mixed with another's silhouette).
    from_face : ndarray of bool, shape (m,)
        Whether the position comes from the face's midpoints.
    cameras : ndarray of int, shape (m,)
        Number of cameras that confirmed the point: those in ``slot``, and those whose merged
        silhouette supports it (``MatchConfig.merged_width_mm``).
    reprojection_rms_px : ndarray, shape (m,)
        RMS of the triangulation's residuals [px].
    sigma_x_mm, sigma_z_mm : ndarray, shape (m,)
        Standard deviation of the position for the features' noise [mm].
    verified : ndarray of bool, shape (m,)
        Confirmed by ``min_cameras``. The others (``MatchConfig.two_view``) are points of two
        cameras whose detections no verified point uses: unverifiable alone, they can only
        continue a wire's track where it predicts them (:mod:`..tracking`).
    radius_mm : ndarray, shape (m,)
        The wire's radius [mm] measured at the point from its bare dark silhouettes
        (:func:`_silhouette_radii`), else in the block from the points that cameras saw the
        outline of on opposite sides only (:func:`_outline_axes`); NaN: not measured (the
        processor's ``wire_radius_mm`` holds).
    """

    scan: IntArray
    slot: IntArray
    x_mm: FloatArray
    z_mm: FloatArray
    from_face: BoolArray
    cameras: IntArray
    reprojection_rms_px: FloatArray
    sigma_x_mm: FloatArray
    sigma_z_mm: FloatArray
    verified: BoolArray
    radius_mm: FloatArray

    @property
    def count(self) -> int:
        return int(self.scan.shape[0])

    def take(self, rows: NDArray[np.integer] | BoolArray) -> Matches:
        """The matches at ``rows`` (indices or a mask)."""
        return Matches(
            scan=self.scan[rows],
            slot=self.slot[rows],
            x_mm=self.x_mm[rows],
            z_mm=self.z_mm[rows],
            from_face=self.from_face[rows],
            cameras=self.cameras[rows],
            reprojection_rms_px=self.reprojection_rms_px[rows],
            sigma_x_mm=self.sigma_x_mm[rows],
            sigma_z_mm=self.sigma_z_mm[rows],
            verified=self.verified[rows],
            radius_mm=self.radius_mm[rows],
        )


def _put(values: FloatArray, rows: NDArray[np.intp], new: FloatArray) -> FloatArray:
    out = values.copy()
    out[rows] = new
    return out


def _again(
    result: TriangulationResult, rows: NDArray[np.intp], again: TriangulationResult
) -> TriangulationResult:
    """``result`` with its ``rows`` triangulated ``again`` (from fewer cameras)."""
    return replace(
        result,
        x_mm=_put(result.x_mm, rows, again.x_mm),
        z_mm=_put(result.z_mm, rows, again.z_mm),
        rms_reprojection_px=_put(result.rms_reprojection_px, rows, again.rms_reprojection_px),
        sigma_x_mm=_put(result.sigma_x_mm, rows, again.sigma_x_mm),
        sigma_z_mm=_put(result.sigma_z_mm, rows, again.sigma_z_mm),
    )


_SILHOUETTE_SLACK_PX = 1.5
"""A bare wire's silhouette may read this much wider than the wire [px]: its two edges'
noise and the blur's asymmetry on a round outline."""
_PROFILE_SPREAD = 0.05
"""A grooved wire's silhouette differs by up to this fraction of its width between views."""


def _widths_mm(
    pinholes: Sequence[LineScanCamera],
    left_px: FloatArray,
    right_px: FloatArray,
    x_mm: FloatArray,
    z_mm: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Each camera's candidate width across its ray at the points [mm] and the resolution
    there [px/mm] (the camera model's): ``(m, C)`` edges [px] and ``(m,)`` points in,
    ``(m, C)`` each out, NaN where a camera has no candidate or the point is NaN."""
    px_per_mm = np.empty(left_px.shape)
    for c, camera in enumerate(pinholes):  # a loop per camera, not per point
        _, du_dx, du_dz = _Geometry.of(camera).project(x_mm, z_mm)
        px_per_mm[:, c] = np.hypot(du_dx, du_dz)  # across the ray: u is constant along it
    with np.errstate(invalid="ignore", divide="ignore"):
        widths: FloatArray = (right_px - left_px) / px_per_mm
    return widths, px_per_mm


def _bare_silhouettes(
    width_mm: FloatArray, px_per_mm: FloatArray, dark: BoolArray, max_width_mm: float
) -> BoolArray:
    """Whether each camera's candidate of the points is one a bare wire can make.

    Its width ``width_mm`` (:func:`_widths_mm`) must be no more than ``max_width_mm``
    (whatever its polarity: a lit part is narrower than its wire) and, for a dark
    silhouette (``dark``), no more than the median of the point's dark silhouettes (the
    wire's own width: objects in line only widen a dark silhouette) by more than
    :data:`_PROFILE_SPREAD`, each give or take :data:`_SILHOUETTE_SLACK_PX` (at
    ``px_per_mm``). A dropper or registration clamp on the wire, or a messenger or a
    crossing wire in line with it, make it wider. ``(m, C)`` each; false where a camera has
    no candidate or the point is NaN."""
    with np.errstate(invalid="ignore"):
        own_mm = (1.0 + _PROFILE_SPREAD) * row_median(np.where(dark, width_mm, np.nan))
        limit_mm = np.where(dark, np.fmin(own_mm, max_width_mm)[:, np.newaxis], max_width_mm)
        bare: BoolArray = width_mm <= limit_mm + _SILHOUETTE_SLACK_PX / px_per_mm
    return bare


def _silhouette_radii(
    width_mm: FloatArray, dark: BoolArray, from_face: BoolArray, config: MatchConfig
) -> FloatArray:
    """Each point's radius [mm] measured from its bare dark silhouettes (against a bright sky
    a round wire's outline is its diameter across the ray, worn or not): half the median of
    its widths ``width_mm`` ``(m, C)`` in the cameras ``dark`` ``(m, C)`` marks, for the
    points located by their silhouettes (not ``from_face``) that two such cameras see and
    whose diameter is a contact wire's (``config``'s narrowest to widest wire, within
    :data:`_PROFILE_SPREAD`: clipped to them); ``(m,)``, NaN elsewhere."""
    diameter = row_median(np.where(dark, width_mm, np.nan))
    lo, hi = config.min_wire_width_mm, config.max_wire_width_mm
    with np.errstate(invalid="ignore"):
        measured = ~from_face & (np.count_nonzero(dark & np.isfinite(width_mm), axis=1) >= 2)
        measured &= (diameter >= (1.0 - _PROFILE_SPREAD) * lo) & (
            diameter <= (1.0 + _PROFILE_SPREAD) * hi
        )
    radii: FloatArray = np.where(measured, 0.5 * np.clip(diameter, lo, hi), np.nan)
    return radii


def _edges(candidates: Candidates, scan: IntArray, slot: IntArray) -> list[FloatArray]:
    """The silhouette's and the face's edges [px] each camera gives the points of ``scan``
    from its candidates ``slot``: ``left, right, face_left, face_right``, each ``(m, C)``,
    NaN where a camera gives none."""
    return _gather(
        scan,
        slot,
        candidates.left_px,
        candidates.right_px,
        candidates.face_left_px,
        candidates.face_right_px,
    )


def _image_points(
    cameras: Sequence[LineScanCamera],
    left_px: FloatArray,
    right_px: FloatArray,
    face_left_px: FloatArray,
    face_right_px: FloatArray,
    config: MatchConfig,
) -> tuple[BoolArray, FloatArray]:
    """Whether each point is located by its face (two cameras at least saw it) and the ideal
    image coordinate of each camera to triangulate: the face's midpoint (the contact point),
    else the silhouette's middle (the axis; a camera's face centre lies a radius below it:
    the two are never mixed). ``(m, C)`` edges [px] in; ``(m,)`` and ``(m, C)`` out, NaN where
    a camera gives nothing."""
    face_mid = 0.5 * (face_left_px + face_right_px)
    from_face = (np.isfinite(face_mid).sum(axis=1) >= 2) & config.contact_from_faces
    u = np.where(from_face[:, np.newaxis], face_mid, 0.5 * (left_px + right_px))
    # on ideal coordinates, with the distortion-free twins of the cameras: the same least
    # squares (the radial term changes the pixel scale by a part in a thousand at most)
    ideal = np.stack([_undistort(camera, u[:, c]) for c, camera in enumerate(cameras)], 1)
    return from_face, ideal


_RADIUS_POINTS = 20
"""Points of a block whose radius was measured (:func:`_outline_axes`) that its median needs."""


def _outline_axes(
    cameras: Sequence[LineScanCamera],
    points_mm: tuple[FloatArray, FloatArray],
    ideal: FloatArray,
    from_face: BoolArray,
    side: NDArray[np.int8],
    left_px: FloatArray,
    right_px: FloatArray,
    config: MatchConfig,
    radius_mm: float,
    measure: bool,
) -> tuple[FloatArray, NDArray[np.intp], float | None]:
    """``ideal`` ``(m, C)`` with the image of each camera whose candidate shows the wire's
    outline on one side only (``side`` ``(m, C)``: -1 the left edge, +1 the right) moved
    from its middle to the wire's axis at the triangulated points ``points_mm`` (``x, z``,
    ``(m,)`` each; :func:`.geometry._outline_axis`) with the radius ``radius_mm``, or the
    one measured here (``measure``), for the points located by their silhouettes; the rows
    changed; and the radius measured [mm] (None: not measured).

    Where three cameras at least see a point and some saw the outline's left edge, others
    its right, the edges bound the wire from both sides: the axis and the radius are fitted
    together (one linearised least-squares step at the point). An assumed radius a
    millimetre off moves such a point by two to five millimetres; the edges' noise moves one
    point's radius by a few tenths, and its height by several times that: the radius taken is
    the median of the block's such points whose radius is a contact wire's (half of
    ``config``'s narrowest to widest wire), where :data:`_RADIUS_POINTS` are."""
    n_cameras = ideal.shape[1]
    x_mm, z_mm = points_mm
    use = (side != 0) & ~from_face[:, np.newaxis] & np.isfinite(x_mm)[:, np.newaxis]
    rows = np.flatnonzero(use.any(axis=1))
    if rows.shape[0] == 0:
        return ideal, rows, None
    x, z = x_mm[rows], z_mm[rows]
    shape = (rows.shape[0], n_cameras)
    u, gx, gz, left, right = (np.empty(shape) for _ in range(5))
    for c, camera in enumerate(cameras):  # a loop per camera, not per point
        u[:, c], gx[:, c], gz[:, c] = _Geometry.of(_pinhole(camera)).project(x, z)
        left[:, c], right[:, c] = (_undistort(camera, v[rows, c]) for v in (left_px, right_px))
    px_per_mm = np.hypot(gx, gz)
    sides = np.where(use[rows], side[rows], 0)
    with np.errstate(invalid="ignore"):
        # (the widest wire's diameter here: one assumed too small would take the one-sided
        # silhouettes of a wider wire for whole ones and never measure it)
        diameter = config.max_wire_width_mm * px_per_mm
        width = right - left
        one = (sides != 0) & ((width < _WHOLE * diameter) | (width * _WHOLE > diameter))
    seen = np.isfinite(ideal[rows])
    fit = (one & (sides < 0)).any(axis=1) & (one & (sides > 0)).any(axis=1)
    fit &= (seen.sum(axis=1) >= 3) & measure
    measured = None
    if np.count_nonzero(fit) >= _RADIUS_POINTS:
        # u(x + dx, z + dz) + side r px_per_mm = edge; u(x + dx, z + dz) = middle elsewhere
        target = np.where(one, np.where(sides < 0, left, right), ideal[rows])
        jacobian = np.stack([gx, gz, np.where(one, sides * px_per_mm, 0.0)], axis=-1)
        jacobian = np.where(seen[..., np.newaxis], jacobian, 0.0)[fit]
        residual = np.where(seen, target - u, 0.0)[fit]
        normal = np.einsum("rci,rcj->rij", jacobian, jacobian)
        step = np.linalg.pinv(normal) @ np.einsum("rci,rc->ri", jacobian, residual)[..., None]
        radii = step[:, 2, 0]
        lo, hi = 0.5 * config.min_wire_width_mm, 0.5 * config.max_wire_width_mm
        radii = radii[(radii >= lo) & (radii <= hi)]
        if radii.shape[0] >= _RADIUS_POINTS:
            measured = float(np.median(radii))
    at_radius = radius_mm if measured is None else measured
    ideal = ideal.copy()
    ideal[rows] = np.where(
        use[rows], _outline_axis(left, right, sides, px_per_mm, at_radius), ideal[rows]
    )
    return ideal, rows, measured


def _triangulate_matches(
    cameras: Sequence[LineScanCamera],
    candidates: Candidates,
    scan: IntArray,
    slot: IntArray,
    sigma_px: FloatArray,
    config: MatchConfig,
    needed: int,
) -> Matches:
    """Step 5: each point from all its cameras (face midpoints where two saw the face).

    A camera whose candidate is wider than a wire can be (:func:`_bare_silhouettes`: a
    clamp on the wire, objects in line) gives no axis, and a dark one a face only clear
    inside it; a point left with one camera has no position (NaN).

    Where a point has a camera to spare, the camera whose image lies furthest outside its
    confirmation window from the point the other cameras give (leave-one-out) is dropped
    and the point triangulated again: an outlier in one of the two cameras a hypothesis was
    built from moves the hypothesis, and the other cameras can still fall in their windows
    of it; at the least-squares point the outlier's error is shared among all the cameras.
    """
    left, right, face_left, face_right = _edges(candidates, scan, slot)
    sigma = float(np.sqrt(np.mean(sigma_px**2))) if sigma_px.size else 0.1
    pinholes = [_pinhole(camera) for camera in cameras]
    from_face, ideal = _image_points(cameras, left, right, face_left, face_right, config)
    result = triangulate(pinholes, ideal, sigma_px=sigma)
    cameras_index = np.arange(slot.shape[1])
    side = np.zeros(slot.shape, dtype=np.int8)
    if candidates.outline_side.any():  # none unless the features look for outlines
        outline = candidates.outline_side[scan[:, np.newaxis], cameras_index, np.maximum(slot, 0)]
        side[slot >= 0] = outline[slot >= 0]
    ideal, rows, measured = _outline_axes(
        cameras,
        (result.x_mm, result.z_mm),
        ideal,
        from_face,
        side,
        left,
        right,
        config,
        config.wire_radius_mm,
        True,
    )
    radius_mm = config.wire_radius_mm if measured is None else measured
    if rows.shape[0]:
        result = _again(result, rows, triangulate(pinholes, ideal[rows], sigma_px=sigma))
    # a candidate wider than a wire can be (a dark silhouette, against a bright sky the
    # wire's outline, also wider than the point's others) is a clamp on the wire or objects
    # in line: its middle is not the wire's, nor is a face reaching a dark one's edges (a worn
    # face clear inside it is; a lit part's face, at night or behind the filter, is its own,
    # and often reaches its end)
    polarity = candidates.polarity[scan[:, np.newaxis], cameras_index, np.maximum(slot, 0)]
    dark = (slot >= 0) & (polarity < 0)
    width_mm, px_per_mm = _widths_mm(pinholes, left, right, result.x_mm, result.z_mm)
    wide = (slot >= 0) & ~_bare_silhouettes(width_mm, px_per_mm, dark, config.max_wire_width_mm)
    radii = _silhouette_radii(width_mm, dark & ~wide, from_face, config)
    with np.errstate(invalid="ignore"):
        clear = (face_left - left > _SILHOUETTE_SLACK_PX) & (
            right - face_right > _SILHOUETTE_SLACK_PX
        )
    lost = wide & dark & ~clear
    rows = np.flatnonzero(wide.any(axis=1))
    if rows.shape[0]:
        slot = np.where(lost, -1, slot)
        left, right = (np.where(wide, np.nan, v)[rows] for v in (left, right))
        face_left, face_right = (np.where(lost, np.nan, v)[rows] for v in (face_left, face_right))
        from_face[rows], ideal[rows] = _image_points(
            cameras, left, right, face_left, face_right, config
        )
        result = _again(result, rows, triangulate(pinholes, ideal[rows], sigma_px=sigma))
        ideal[rows], again, _ = _outline_axes(
            cameras,
            (result.x_mm[rows], result.z_mm[rows]),
            ideal[rows],
            from_face[rows],
            side[rows],
            left,
            right,
            config,
            radius_mm,
            False,
        )
        if again.shape[0]:
            rows = rows[again]
            result = _again(result, rows, triangulate(pinholes, ideal[rows], sigma_px=sigma))
    window = np.maximum(config.confirm_sigmas * sigma_px, config.floor_px)[np.newaxis, :]
    # leave-one-out, linearised: camera i's residual at the point the others give is
    # r_i / (1 - h_i), h_i = j_iᵀ (JᵀJ)⁻¹ j_i its leverage (j_i its row of the Jacobian)
    seen = np.isfinite(ideal)
    # the pinholes' projection and its gradient (LineScanCamera.project_jacobian), (m, C)
    m00, m01, m02, m10, m11, m12 = np.array(
        [camera.matrix.ravel() for camera in pinholes], dtype=np.float64
    ).T[:, np.newaxis, :]
    x, z = result.x_mm[:, np.newaxis], result.z_mm[:, np.newaxis]
    with np.errstate(invalid="ignore", divide="ignore"):
        den = m10 * x + m11 * z + m12
        u_c = (m00 * x + m01 * z + m02) / den
        residual = np.where(seen, u_c - ideal, 0.0)
        jx = np.where(seen, (m00 - u_c * m10) / den, 0.0)
        jz = np.where(seen, (m01 - u_c * m11) / den, 0.0)
    n11 = (jx * jx).sum(axis=1)[:, np.newaxis]
    n12 = (jx * jz).sum(axis=1)[:, np.newaxis]
    n22 = (jz * jz).sum(axis=1)[:, np.newaxis]
    with np.errstate(invalid="ignore", divide="ignore"):
        leverage = (jx * jx * n22 - 2.0 * jx * jz * n12 + jz * jz * n11) / (n11 * n22 - n12**2)
        excess = np.abs(residual) / np.maximum(1.0 - leverage, 1e-3) / window
    excess = np.where(seen & np.isfinite(excess), excess, 0.0)
    spare = seen.sum(axis=1) > needed
    worst = np.argmax(excess, axis=1)
    drop = spare & (excess[np.arange(scan.shape[0]), worst] > 1.0)
    rows, worst = np.flatnonzero(drop), worst[drop]
    if rows.shape[0]:
        slot = slot.copy()
        slot[rows, worst] = -1
        ideal[rows, worst] = np.nan
        result = _again(result, rows, triangulate(pinholes, ideal[rows], sigma_px=sigma))
    return Matches(
        scan=scan,
        slot=slot,
        x_mm=result.x_mm,
        z_mm=result.z_mm,
        from_face=from_face,
        cameras=(slot >= 0).sum(axis=1).astype(np.int64),
        reprojection_rms_px=result.rms_reprojection_px,
        sigma_x_mm=result.sigma_x_mm,
        sigma_z_mm=result.sigma_z_mm,
        verified=np.ones(scan.shape[0], dtype=bool),
        radius_mm=np.where(np.isfinite(radii), radii, np.nan if measured is None else measured),
    )
