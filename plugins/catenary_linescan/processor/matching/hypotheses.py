"""Stereo matching of wire candidates across N line-scan cameras (the paper's section 3.1).

The paper's trinocular check (figure 4), generalised to any number of cameras and vectorised
over the scans of a block:

1. **Pad** each camera's candidates (profile features) to ``(n, C, K)`` arrays: ``n`` scans,
   ``C`` cameras, ``K`` candidates at most per scan and camera (:func:`pad_candidates`).
2. **Enumerate** (step 1 of the paper): for camera pairs ``(a, b)`` triangulate all ``K x K``
   combinations of their candidates with the closed form (eq. 9-10), keeping points in front
   of both cameras and inside the plausible volume above the roof. Not every pair is needed:
   only pairs meeting every set of ``min_cameras`` cameras (:func:`covering_pairs`: two of
   the six for four cameras and three needed).
3. **Verify** (steps 2-3): re-project each point into every other camera ``c`` and look up the
   nearest candidate there (one ``searchsorted`` over the block). It confirms the point when
   it lies within ``max(k · σ, floor_px)`` of the re-projection, where ``σ`` combines camera
   ``c``'s own uncertainty with those of ``a`` and ``b`` carried through the triangulation::

       σ² = σ_c² + (∂u_c/∂u_a)² σ_a² + (∂u_c/∂u_b)² σ_b²,   σ_i² = rms_i² + σ_feature²

   ``rms_i`` is camera ``i``'s calibration reprojection RMS (the paper's "average deviation
   distance of re-projection") and ``σ_feature`` the features' centre uncertainty. The
   derivatives grow when the rays of ``a`` and ``b`` meet at a shallow angle, so a point from
   two close cameras gets the wider window it needs and one from a wide baseline a narrow one.
   Candidates of opposite polarity (bright on dark against dark on bright) never match.
4. **Resolve** conflicts so that each detection is used once (:func:`_resolve`): greedy by
   score (cameras confirming first, then the normalised residual), vectorised across the
   scans of the block in rounds; then a detection may be lent by a point with a camera to
   spare to one that needs it (two objects in line in one camera), and a merged silhouette
   (several objects in line, its centre and face belonging to none) supports the points whose
   images it holds. A point needs ``min_cameras`` cameras: 3 by default with three or more
   cameras (two views always intersect, so only a third verifies), which keeps a 4-camera rig
   working with one camera blinded by the sun or missing a wire.
5. **Triangulate** each accepted point from all the cameras that confirmed it (least squares
   on the rays, then Gauss-Newton on the reprojection error:
   :func:`catenary_linescan.triangulation.triangulate`), from the worn face's midpoints where
   two cameras at least saw the face (the contact point), else from the middles of the
   wire's silhouettes (its axis), with a leave-one-out check that drops a camera whose image
   the others do not predict.
6. **Two views**: points of two cameras made of the detections left unused, where both saw a
   face, are returned unverified (``Matches.verified``): tracking takes them only where they
   continue a wire it follows (a blind camera and a missed detection at once).
7. **Separate**: of two points of a scan closer than two wires can be apart (30 mm), the
   weaker is one wire seen twice and goes.

:func:`face_widths_mm` then measures the worn face of each point in every confirming camera:
the rays through the face's two edges are cut with the face's plane through the contact point
(horizontal in the track frame, so tilted by the body's roll in the roof frame), which is the
camera model's exact resolution there; the rig's resolution look-up table times the width in
pixels is the cross-check. The cameras' widths are combined robustly (median, then the
precision-weighted mean of the cameras that agree with it).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from catenary_linescan.calibration import ResolutionTable
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.triangulation import triangulate

__all__ = [
    "Candidates",
    "FaceWidths",
    "FeatureTable",
    "MatchConfig",
    "Matches",
    "camera_sigmas_px",
    "covering_pairs",
    "face_widths_mm",
    "lit_chord_mm",
    "match",
    "pad_candidates",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]


class FeatureTable(Protocol):
    """One camera's profile features for a block of scans, flattened: fields shape (m,).

    ``scan`` is the scan's index within the block; pixel positions follow FORMATS.md.
    ``polarity`` is +1 for a candidate brighter than its background, -1 darker, 0 unknown.
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


@dataclass(frozen=True)
class MatchConfig:
    """Settings of the matching (lengths in mm, image coordinates in px).

    Attributes
    ----------
    max_candidates : int
        Most candidates kept per scan and camera (the strongest by contrast): ``K``'s cap.
        The field's systems follow 10-12 wires; with messengers and fittings 24 leaves room.
    feature_sigma_px : float
        Standard deviation of a candidate's centre from the features [px].
    confirm_sigmas : float
        Confirmation window in standard deviations of the predicted residual (``k``).
    floor_px : float
        Narrowest confirmation window [px]: a floor under ``k · σ`` for what the noise model
        does not hold (blur, a wire's outline seen from different sides).
    min_cameras : int or None
        Cameras a point needs; None: 3 with three cameras or more, else 2.
    x_range_mm, z_range_mm : tuple of float
        Roof-frame volume in which points are plausible (messengers included).
    match_polarity : bool
        Candidates of opposite (non-zero) polarity never match.
    contact_from_faces : bool
        Triangulate the contact point from the face's midpoints where two cameras at least
        saw the face (else the wire's axis from the middles of its silhouettes).
    support_merged : bool
        Let merged silhouettes support points (step 4 of the module docstring).
    covering_pairs : bool
        Enumerate only the camera pairs that meet every set of ``min_cameras`` cameras
        (:func:`covering_pairs`), else every pair.
    two_view : bool
        Also return the points of two cameras made of detections left unused (unverified,
        ``Matches.verified`` false) where both saw a worn face, for tracking to take where
        they continue a wire.
    min_separation_mm : float
        Two points of one scan closer than this are one wire seen twice; the weaker goes
        (:func:`_separate`). Wires are 11-15 mm thick: two closer than this touch.
    """

    max_candidates: int = 24
    feature_sigma_px: float = 0.15
    confirm_sigmas: float = 4.0
    floor_px: float = 0.6
    min_cameras: int | None = None
    x_range_mm: tuple[float, float] = (-3000.0, 3000.0)
    z_range_mm: tuple[float, float] = (300.0, 6000.0)
    match_polarity: bool = True
    contact_from_faces: bool = True
    support_merged: bool = True
    covering_pairs: bool = True
    two_view: bool = True
    min_separation_mm: float = 30.0

    def cameras_needed(self, cameras: int) -> int:
        if self.min_cameras is not None:
            return max(2, min(self.min_cameras, cameras))
        return 3 if cameras >= 3 else 2


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
    detection: IntArray

    @property
    def shape(self) -> tuple[int, int, int]:
        n, c, k = self.centre_px.shape
        return int(n), int(c), int(k)


def pad_candidates(
    features: Sequence[FeatureTable], scans: int, max_candidates: int = 24
) -> Candidates:
    """Gather flat per-camera features into ``(n, C, K)`` arrays.

    Parameters
    ----------
    features : sequence of FeatureTable, length C
        One flat table per camera, in the rig's camera order.
    scans : int
        Scans in the block (``n``); ``scan`` values must lie in ``[0, n)``.
    max_candidates : int
        Cap on ``K``; in a scan with more candidates the weakest (lowest contrast) are dropped.

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
        for name, values in out.items():
            values[scan_kept, column, slot] = np.asarray(getattr(table, name), np.float64)[rows]
        contrast[scan_kept, column, slot] = strength[rows]
        polarity[scan_kept, column, slot] = np.asarray(table.polarity)[rows]
        detection[scan_kept, column, slot] = rows
    return Candidates(
        centre_px=out["centre_px"],
        left_px=out["left_px"],
        right_px=out["right_px"],
        face_left_px=out["face_left_px"],
        face_right_px=out["face_right_px"],
        contrast=contrast,
        polarity=polarity,
        detection=detection,
    )


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
        continue a wire's track where it predicts them (:mod:`.tracking`).
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
        )


def camera_sigmas_px(reprojection_rms_px: Sequence[float], feature_sigma_px: float) -> FloatArray:
    """Per-camera standard deviation of a candidate's centre [px], shape (C,).

    ``sqrt(rms² + σ_feature²)``; an unknown (NaN) calibration RMS counts as 0.5 px.
    """
    rms = np.asarray(reprojection_rms_px, dtype=np.float64)
    rms = np.where(np.isfinite(rms), rms, 0.5)
    return np.asarray(np.hypot(rms, feature_sigma_px), dtype=np.float64)


# -- geometry helpers ------------------------------------------------------------------------


@dataclass(frozen=True)
class _Geometry:
    """A camera's ideal (undistorted) model in arrays: ``M``, centre and optical axis."""

    m: FloatArray
    centre: FloatArray
    axis: FloatArray

    @classmethod
    def of(cls, camera: LineScanCamera) -> _Geometry:
        # the centre and axis cost tens of microseconds: computed once per camera model
        matrix = camera.matrix
        key = matrix.tobytes()
        geometry = _geometries.get(key)
        if geometry is None:
            geometry = cls(matrix.copy(), camera.centre_mm, camera.optical_axis)
            _geometries[key] = geometry
        return geometry

    def depth(self, x: FloatArray, z: FloatArray) -> FloatArray:
        return np.asarray(
            self.axis[0] * (x - self.centre[0]) + self.axis[1] * (z - self.centre[1]), np.float64
        )

    def project(self, x: FloatArray, z: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Ideal ``u`` and its gradient ``(du/dx, du/dz)`` at roof-frame points."""
        m = self.m
        with np.errstate(divide="ignore", invalid="ignore"):
            den = m[1, 0] * x + m[1, 1] * z + m[1, 2]
            u = (m[0, 0] * x + m[0, 1] * z + m[0, 2]) / den
            gx = (m[0, 0] - u * m[1, 0]) / den
            gz = (m[0, 1] - u * m[1, 1]) / den
        return u, gx, gz


_geometries: dict[bytes, _Geometry] = {}


def _line_coefficients(m: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Equation 10's ``p, q, k``: the ray of ideal coordinate ``u`` is ``p x + q z = k``."""
    return m[0, 0] - u * m[1, 0], m[0, 1] - u * m[1, 1], u * m[1, 2] - m[0, 2]


@dataclass(frozen=True)
class _Sorted:
    """One camera's candidates sorted along each scan's line, flattened with row offsets, so
    that one ``searchsorted`` finds the nearest candidate for queries from any scans.

    Every field is flat, ``(n * K,)``, in sorted position: ``slot`` the candidate's index
    along ``K``, ``value`` its coordinate, ``left`` and ``right`` its silhouette's edges,
    ``polarity`` its polarity; a query's position indexes them all with 1-D takes.
    """

    keys: FloatArray  # ascending
    slot: NDArray[np.intp]
    value: FloatArray
    left: FloatArray
    right: FloatArray
    polarity: NDArray[np.int8]
    k: int
    span: float

    @classmethod
    def of(
        cls,
        values: FloatArray,
        left: FloatArray,
        right: FloatArray,
        polarity: NDArray[np.int8],
        span: float,
    ) -> _Sorted:
        n, k = values.shape
        by_position = np.where(np.isnan(values), np.inf, values)
        if np.all(by_position[:, 1:] >= by_position[:, :-1]):
            # the usual case (pad_candidates sorts along the line): already in order
            slot = np.tile(np.arange(k), n)
            ordered, left, right, polarity = (v.ravel() for v in (values, left, right, polarity))
        else:
            order = np.argsort(by_position, axis=1, kind="stable")
            flat = (order + (np.arange(n) * k)[:, np.newaxis]).ravel()
            slot = order.ravel()
            ordered, left, right, polarity = (
                v.ravel()[flat] for v in (values, left, right, polarity)
            )
        offset = np.repeat(np.arange(n, dtype=np.float64) * (4.0 * span), k)
        keys = np.where(np.isnan(ordered), 1.5 * span, np.clip(ordered, -span, span)) + offset
        return cls(keys, slot, ordered, left, right, polarity, k, span)

    def nearest(
        self,
        rows: tuple[FloatArray, NDArray[np.intp], NDArray[np.intp]],
        query: FloatArray,
    ) -> tuple[NDArray[np.intp], FloatArray]:
        """Sorted position of the candidate nearest each query in its scan, and
        ``query - candidate``.

        ``rows`` holds, for each query's scan ``s``, the offset of its keys ``4 s · span``
        and its first and last sorted positions ``s K`` and ``s K + K - 1`` (the same for
        every camera); they and ``query`` are ``(h,)``. The residual is NaN where the scan
        has no candidate or the query is NaN.
        """
        offset, row_start, row_end = rows
        span = self.span
        q = np.where(np.isnan(query), 0.0, np.clip(query, -span, span)) + offset
        # q lies within its row's keys' band and 2.5 spans clear of the others': the
        # position is in [row_start, row_end + 1]
        position = np.searchsorted(self.keys, q)
        lower = np.maximum(position - 1, row_start)
        upper = np.minimum(position, row_end)
        keys = self.keys
        pick = np.where(np.abs(keys[upper] - q) < np.abs(keys[lower] - q), upper, lower)
        return pick, query - self.value[pick]


# -- the matching -----------------------------------------------------------------------------


def covering_pairs(centres: Sequence[FloatArray], needed: int) -> list[tuple[int, int]]:
    """Camera pairs to enumerate so that every point seen by ``needed`` cameras is found.

    A point confirmed by a set of ``needed`` cameras or more is enumerated from any pair
    inside that set, so the pairs need only meet every ``needed``-subset of the cameras, not
    be all of them: with four cameras and three needed, two pairs (``{1, 4}`` and ``{2, 3}``)
    meet all four triples, a third of the work of all six. Chosen greedily: the pair meeting
    the most subsets not yet met, the wider baseline first (better-conditioned points).

    Parameters
    ----------
    centres : sequence of ndarray (2,)
        Camera centres in the roof frame [mm], in camera order.
    needed : int
        Cameras a point needs (2: every pair is needed).

    Returns
    -------
    list of (int, int)
        Camera index pairs ``(a, b)`` with ``a < b``.
    """
    cameras = len(centres)
    pairs = list(itertools.combinations(range(cameras), 2))
    if needed <= 2:
        return pairs
    baseline = {
        (a, b): float(np.hypot(*(np.asarray(centres[a]) - np.asarray(centres[b]))))
        for a, b in pairs
    }
    uncovered = {frozenset(s) for s in itertools.combinations(range(cameras), needed)}
    chosen: list[tuple[int, int]] = []
    while uncovered:
        best = max(
            pairs,
            key=lambda p: (sum(1 for s in uncovered if p[0] in s and p[1] in s), baseline[p]),
        )
        chosen.append(best)
        uncovered = {s for s in uncovered if not (best[0] in s and best[1] in s)}
    return sorted(chosen)


def _covering_pairs(geometry: Sequence[_Geometry], needed: int) -> list[tuple[int, int]]:
    """:func:`covering_pairs` of the cameras' centres, computed once per rig."""
    key = (b"".join(g.centre.tobytes() for g in geometry), needed)
    pairs = _covering.get(key)
    if pairs is None:
        pairs = _covering[key] = covering_pairs([g.centre for g in geometry], needed)
    return pairs


_covering: dict[tuple[bytes, int], list[tuple[int, int]]] = {}


@dataclass(frozen=True)
class _Hypotheses:
    """Candidate points confirmed by ``min_cameras`` cameras at least: fields ``(h, ...)``."""

    scan: NDArray[np.intp]  # (h,)
    slot: NDArray[np.int64]  # (h, C), -1: camera not in the hypothesis
    count: NDArray[np.int64]  # (h,) cameras whose detection confirms it (the pair's included)
    inside: NDArray[np.int64]  # (h, C) unconfirming candidate whose silhouette holds it, or -1
    chi2: FloatArray  # (h,) sum of squared normalised residuals of the confirmations


def _pairs_of(
    valid_a: NDArray[np.bool_], valid_b: NDArray[np.bool_]
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Flat ``(n * K)`` indices of every combination of a valid candidate of camera ``a``
    with one of camera ``b`` in the same scan, in the order of ``np.nonzero`` over
    ``(scan, slot_a, slot_b)``."""
    k = valid_a.shape[1]
    ia = np.flatnonzero(valid_a)
    ib = np.flatnonzero(valid_b)
    count_b = np.count_nonzero(valid_b, axis=1)
    start_b = np.cumsum(count_b) - count_b
    scan_a = ia // k
    reps = count_b[scan_a]
    rows_a = np.repeat(ia, reps)
    ends = np.cumsum(reps)
    within = np.arange(rows_a.shape[0]) - np.repeat(ends - reps, reps)
    rows_b = ib[np.repeat(start_b[scan_a], reps) + within]
    return rows_a, rows_b


def _enumerate_by_pair(
    geometry: Sequence[_Geometry],
    u: FloatArray,
    silhouette: tuple[FloatArray, FloatArray],
    polarity: NDArray[np.int8],
    sigma: FloatArray,
    config: MatchConfig,
    span: float,
    needed: int,
    pairs: Sequence[tuple[int, int]],
) -> _Hypotheses:
    """Steps 2-3 of the module docstring, one camera pair at a time (many scans: the
    pair's arrays stay in the cache and its cameras' coefficients are scalars)."""
    _, n_cameras, k = u.shape
    # per camera, flat (n * K,) and contiguous: 1-D takes are far cheaper than 3-index ones
    u_of = [np.ascontiguousarray(u[:, c, :]) for c in range(n_cameras)]
    pol_of = [np.ascontiguousarray(polarity[:, c, :]).ravel() for c in range(n_cameras)]
    lines = [
        [v.ravel() for v in _line_coefficients(geometry[c].m, u_of[c])] for c in range(n_cameras)
    ]
    valid = [np.isfinite(v) for v in u_of]
    sorted_u: dict[int, _Sorted] = {}
    parts: list[_Hypotheses] = []
    x_lo, x_hi = config.x_range_mm
    z_lo, z_hi = config.z_range_mm
    for a, b in pairs:
        ga, gb = geometry[a], geometry[b]
        # all combinations of a valid candidate of a with one of b in the same scan
        rows_a, rows_b = _pairs_of(valid[a], valid[b])
        pa, qa, ka = (v[rows_a] for v in lines[a])
        pb, qb, kb = (v[rows_b] for v in lines[b])
        with np.errstate(divide="ignore", invalid="ignore"):
            det = pa * qb - pb * qa
            x = (qb * ka - qa * kb) / det
            z = (pa * kb - pb * ka) / det
            ok = (x >= x_lo) & (x <= x_hi) & (z >= z_lo) & (z <= z_hi)
        pol_a, pol_b = pol_of[a][rows_a], pol_of[b][rows_b]
        if config.match_polarity:
            ok &= (pol_a * pol_b) >= 0
        with np.errstate(invalid="ignore"):
            ok &= (ga.depth(x, z) > 0.0) & (gb.depth(x, z) > 0.0)
        keep = np.flatnonzero(ok)
        rows_a, rows_b, x, z, pa, qa, pb, qb, pol_a, pol_b = (
            v[keep] for v in (rows_a, rows_b, x, z, pa, qa, pb, qb, pol_a, pol_b)
        )
        scan = rows_a // k
        h = scan.shape[0]
        pol = np.where(pol_a != 0, pol_a, pol_b)
        slot_cols: list[NDArray[np.int64] | None] = [None] * n_cameras
        inside_cols: list[NDArray[np.int64] | None] = [None] * n_cameras
        row_start = scan * k
        slot_cols[a] = rows_a - row_start
        slot_cols[b] = rows_b - row_start
        scan_rows = (scan * (4.0 * span), row_start, row_start + (k - 1))  # for nearest
        count = np.full(h, 2, dtype=np.int64)
        held = np.zeros(h, dtype=np.int64)
        chi2 = np.zeros(h)
        # gradients of u_a and u_b, for the uncertainty carried through the triangulation
        _, gax, gaz = ga.project(x, z)
        _, gbx, gbz = gb.project(x, z)
        with np.errstate(invalid="ignore", divide="ignore"):
            den_a = gax * qb - gaz * pb
            den_b = gbx * qa - gbz * pa
        for c in range(n_cameras):
            if c in (a, b):
                continue
            if c not in sorted_u:
                sorted_u[c] = _Sorted.of(
                    u_of[c], silhouette[0][:, c, :], silhouette[1][:, c, :], polarity[:, c, :], span
                )
            sc = sorted_u[c]
            gc = geometry[c]
            uc, gcx, gcz = gc.project(x, z)
            with np.errstate(invalid="ignore", divide="ignore"):
                # moving u_a moves the point along b's ray (qb, -pb), and vice versa
                da = (gcx * qb - gcz * pb) / den_a
                db = (gcx * qa - gcz * pa) / den_b
                variance = sigma[c] ** 2 + (da * sigma[a]) ** 2 + (db * sigma[b]) ** 2
                window = np.maximum(config.confirm_sigmas * np.sqrt(variance), config.floor_px)
                query = np.where(gc.depth(x, z) > 0.0, uc, np.nan)
            pick, residual = sc.nearest(scan_rows, query)
            found = sc.slot[pick]
            with np.errstate(invalid="ignore"):
                confirmed = np.abs(residual) <= window
                # the image falls inside a candidate whose centre does not confirm it:
                # perhaps a merged silhouette (step 4 decides)
                within = (query >= sc.left[pick]) & (query <= sc.right[pick])
            if config.match_polarity:
                same = (pol * sc.polarity[pick]) >= 0
                confirmed &= same
                within &= same
            slot_cols[c] = np.where(confirmed, found, -1)
            count += confirmed
            chi2 += np.where(confirmed, residual * residual / variance, 0.0)
            inside_c = within & ~confirmed
            inside_cols[c] = np.where(inside_c, found, -1)
            held += inside_c
        # with two cameras confirming, merged silhouettes may still bring it to ``needed``
        possible = count + held if config.support_merged else count
        keep = np.flatnonzero(possible >= needed)
        minus = np.full(keep.shape[0], -1, dtype=np.int64)
        parts.append(
            _Hypotheses(
                scan[keep],
                np.stack([minus if s is None else s[keep] for s in slot_cols], axis=1).astype(
                    np.int64
                ),
                count[keep],
                np.stack([minus if s is None else s[keep] for s in inside_cols], axis=1).astype(
                    np.int64
                ),
                chi2[keep],
            )
        )
    return _Hypotheses(
        np.concatenate([p.scan for p in parts]),
        np.concatenate([p.slot for p in parts]),
        np.concatenate([p.count for p in parts]),
        np.concatenate([p.inside for p in parts]),
        np.concatenate([p.chi2 for p in parts]),
    )


_ENUMERATE_GROUP_ROWS = 1024
"""Scans times pairs above which ``_enumerate`` takes the camera pairs one at a time
(:func:`_enumerate_by_pair`): with few scans (the leftovers' passes) all pairs at once save
NumPy calls, a microsecond or so each however few the rows; with many, one pair's arrays
stay in the cache and its cameras' coefficients are scalars."""


def _enumerate(
    geometry: Sequence[_Geometry],
    u: FloatArray,
    silhouette: tuple[FloatArray, FloatArray],
    polarity: NDArray[np.int8],
    sigma: FloatArray,
    config: MatchConfig,
    span: float,
    needed: int,
    pairs: Sequence[tuple[int, int]],
) -> _Hypotheses:
    """Steps 2-3 of the module docstring for the given camera pairs.

    Vectorised over the pairs as well as the scans where the scans are few: every array
    has a row per combination (or hypothesis), its cameras' coefficients gathered per row,
    so that the count of NumPy calls (a microsecond or so each, however few the rows) does
    not grow with the pairs. The arithmetic per row is that of one pair at a time.
    """
    n, n_cameras, k = u.shape
    if n * len(pairs) > _ENUMERATE_GROUP_ROWS:
        return _enumerate_by_pair(
            geometry, u, silhouette, polarity, sigma, config, span, needed, pairs
        )
    if not pairs or n == 0:
        empty = np.zeros(0, dtype=np.int64)
        none = np.zeros((0, n_cameras), dtype=np.int64)
        return _Hypotheses(empty.astype(np.intp), none, empty, none.copy(), np.zeros(0))
    # per camera: M's coefficients, optical axis, centre, sigma: rows of (11, C)
    coef = np.array(
        [[*g.m[:2].ravel(), *g.axis[:2], *g.centre[:2]] for g in geometry],
        dtype=np.float64,
    ).T
    coef = np.concatenate([coef, np.asarray(sigma, np.float64)[np.newaxis, :]])
    m00, m01, m02, m10, m11, m12 = (v[np.newaxis, :, np.newaxis] for v in coef[:6])
    # equation 10's lines of every candidate, flat over (n, C, K)
    p_all = (m00 - u * m10).ravel()
    q_all = (m01 - u * m11).ravel()
    k_all = (u * m12 - m02).ravel()
    pol_all = polarity.ravel()
    valid = np.isfinite(u)
    count = np.count_nonzero(valid, axis=2)  # (n, C)
    valid_rows = np.flatnonzero(valid)  # by scan, camera and slot
    valid_start = np.cumsum(count.ravel()) - count.ravel()  # of each (scan, camera)
    # each camera's candidates sorted along each scan's line, camera-major (C, n, K), with
    # row offsets: one search per pair and camera finds the nearest for all its rows
    values = u.transpose(1, 0, 2)
    by_position = np.where(np.isnan(values), np.inf, values)
    if np.all(by_position[:, :, 1:] >= by_position[:, :, :-1]):
        # the usual case (pad_candidates sorts along the line): the stable sort's order
        order = np.broadcast_to(np.arange(k), values.shape)
    else:
        order = np.argsort(by_position, axis=2, kind="stable")
    flat = (order + (np.arange(n_cameras * n) * k).reshape(n_cameras, n, 1)).ravel()
    ordered = values.ravel()[flat]
    offset = np.tile(np.repeat(np.arange(n, dtype=np.float64) * (4.0 * span), k), n_cameras)
    keys = np.where(np.isnan(ordered), 1.5 * span, np.clip(ordered, -span, span)) + offset
    keys_of = keys.reshape(n_cameras, n * k)
    sorted_slot = order.ravel()
    sorted_left = silhouette[0].transpose(1, 0, 2).ravel()[flat]
    sorted_right = silhouette[1].transpose(1, 0, 2).ravel()[flat]
    sorted_pol = polarity.transpose(1, 0, 2).ravel()[flat]
    x_lo, x_hi = config.x_range_mm
    z_lo, z_hi = config.z_range_mm

    def enumerate_pairs(group: Sequence[tuple[int, int]]) -> _Hypotheses:
        pair_a = np.array([a for a, _ in group], dtype=np.intp)
        pair_b = np.array([b for _, b in group], dtype=np.intp)
        others = np.array(
            [[c for c in range(n_cameras) if c not in pair] for pair in group], dtype=np.intp
        ).reshape(len(group), n_cameras - 2)
        single = len(group) == 1

        def per_row(table: FloatArray, pair: NDArray[np.intp]) -> list[FloatArray]:
            """The coefficients of each row's camera (scalars for one pair)."""
            return [v[0] for v in table] if single else [v[pair] for v in table]

        # all combinations of a valid candidate of a with one of b in the same scan, by
        # pair, then scan, a's slot and b's slot (the order of np.nonzero over K x K)
        entry = np.flatnonzero(valid[:, pair_a, :].transpose(1, 0, 2))  # over (P, n, K)
        pair = entry // (n * k)
        scan = (entry // k) % n
        slot_a = entry % k
        reps = count[scan, pair_b[pair]]
        starts = np.cumsum(reps) - reps
        # np.repeat by counts copies element by element: the entry of each combination
        # from a running count of the entries' starts instead
        filled = np.flatnonzero(reps)
        mark = np.zeros(int(starts[-1] + reps[-1]) if reps.shape[0] else 0, dtype=np.intp)
        mark[starts[filled[1:]]] = 1
        of = filled[np.cumsum(mark)]
        pair, scan, slot_a = pair[of], scan[of], slot_a[of]
        within = np.arange(of.shape[0]) - starts[of]
        row_a = (scan * n_cameras + pair_a[pair]) * k + slot_a
        row_b = valid_rows[valid_start[scan * n_cameras + pair_b[pair]] + within]
        slot_b = row_b % k
        pa, qa, ka = p_all[row_a], q_all[row_a], k_all[row_a]
        pb, qb, kb = p_all[row_b], q_all[row_b], k_all[row_b]
        ca = per_row(coef[6:10, pair_a], pair)
        cb = per_row(coef[6:10, pair_b], pair)
        with np.errstate(divide="ignore", invalid="ignore"):
            det = pa * qb - pb * qa
            x = (qb * ka - qa * kb) / det
            z = (pa * kb - pb * ka) / det
            ok = (x >= x_lo) & (x <= x_hi) & (z >= z_lo) & (z <= z_hi)
            ok &= ca[0] * (x - ca[2]) + ca[1] * (z - ca[3]) > 0.0
            ok &= cb[0] * (x - cb[2]) + cb[1] * (z - cb[3]) > 0.0
        pol_a, pol_b = pol_all[row_a], pol_all[row_b]
        if config.match_polarity:
            ok &= (pol_a * pol_b) >= 0
        pol = np.where(pol_a != 0, pol_a, pol_b)
        keep = np.flatnonzero(ok)
        pair, scan, slot_a, slot_b, x, z, pa, qa, pb, qb, pol = (
            v[keep] for v in (pair, scan, slot_a, slot_b, x, z, pa, qa, pb, qb, pol)
        )
        bounds = np.searchsorted(pair, np.arange(len(group) + 1)).tolist()
        # M's coefficients (0-5) and sigma (10) of a and b
        ca = per_row(coef[_PROJECTION, :][:, pair_a], pair)
        cb = per_row(coef[_PROJECTION, :][:, pair_b], pair)
        h = scan.shape[0]
        # each row's column in (h, C): one column for one pair
        rows: slice | NDArray[np.intp] = slice(None) if single else np.arange(h)
        slot = np.full((h, n_cameras), -1, dtype=np.int64)
        slot[rows, int(pair_a[0]) if single else pair_a[pair]] = slot_a
        slot[rows, int(pair_b[0]) if single else pair_b[pair]] = slot_b
        hits = np.full(h, 2, dtype=np.int64)
        inside = np.full((h, n_cameras), -1, dtype=np.int64)
        chi2 = np.zeros(h)

        def project(c: list[FloatArray]) -> tuple[FloatArray, FloatArray, FloatArray]:
            den = c[3] * x + c[4] * z + c[5]
            u_c = (c[0] * x + c[1] * z + c[2]) / den
            return u_c, (c[0] - u_c * c[3]) / den, (c[1] - u_c * c[4]) / den

        with np.errstate(invalid="ignore", divide="ignore"):
            # gradients of u_a and u_b, for the uncertainty carried through the triangulation
            _, gax, gaz = project(ca)
            _, gbx, gbz = project(cb)
            # moving u_a moves the point along b's ray (qb, -pb), and vice versa
            den_a = gax * qb - gaz * pb
            den_b = gbx * qa - gbz * pa
            for j in range(n_cameras - 2):
                cam_c = int(others[0, j]) if single else others[pair, j]
                cc = per_row(coef[:, others[:, j]], pair)
                uc, gcx, gcz = project(cc)
                da = (gcx * qb - gcz * pb) / den_a
                db = (gcx * qa - gcz * pa) / den_b
                variance = cc[10] ** 2 + (da * ca[6]) ** 2 + (db * cb[6]) ** 2
                window = np.maximum(config.confirm_sigmas * np.sqrt(variance), config.floor_px)
                query = np.where(cc[6] * (x - cc[8]) + cc[7] * (z - cc[9]) > 0.0, uc, np.nan)
                # the nearest candidate in camera c's row of the scan
                q = np.where(np.isnan(query), 0.0, np.clip(query, -span, span)) + scan * (
                    4.0 * span
                )
                position = np.empty(h, dtype=np.intp)
                for p, c in enumerate(others[:, j].tolist()):
                    first, last = bounds[p], bounds[p + 1]
                    position[first:last] = np.searchsorted(keys_of[c], q[first:last]) + c * n * k
                # in [row_start, row_start + k], as in _Sorted.nearest
                row_start = (cam_c * n + scan) * k
                lower = np.maximum(position - 1, row_start)
                upper = np.minimum(position, row_start + (k - 1))
                pick = np.where(np.abs(keys[upper] - q) < np.abs(keys[lower] - q), upper, lower)
                residual = query - ordered[pick]
                found = sorted_slot[pick]
                confirmed = np.abs(residual) <= window
                # the image falls inside a candidate whose centre does not confirm it:
                # perhaps a merged silhouette (step 4 decides)
                held = (query >= sorted_left[pick]) & (query <= sorted_right[pick])
                if config.match_polarity:
                    same = (pol * sorted_pol[pick]) >= 0
                    confirmed &= same
                    held &= same
                slot[rows, cam_c] = np.where(confirmed, found, -1)
                hits += confirmed
                chi2 += np.where(confirmed, residual * residual / variance, 0.0)
                inside[rows, cam_c] = np.where(held & ~confirmed, found, -1)
        # with two cameras confirming, merged silhouettes may still bring it to ``needed``
        possible = hits + (inside >= 0).sum(axis=1) if config.support_merged else hits
        keep = np.flatnonzero(possible >= needed)
        return _Hypotheses(scan[keep], slot[keep], hits[keep], inside[keep], chi2[keep])

    return enumerate_pairs(pairs)


_PROJECTION = [0, 1, 2, 3, 4, 5, 10]
"""Rows of ``_enumerate``'s table of camera coefficients for the projection, and sigma."""


_BORROW_MAX_CHI2 = 1.0
"""Largest mean squared normalised residual of a hypothesis that may borrow a detection."""


def _first_per_scan(scan: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Mask of the first entry of each run of equal values in a sorted array."""
    first = np.ones(scan.shape[0], dtype=bool)
    first[1:] = scan[1:] != scan[:-1]
    return first


def _resolve(
    hypotheses: _Hypotheses,
    n: int,
    k: int,
    needed: int,
    more: Callable[[IntArray, NDArray[np.bool_]], _Hypotheses] | None = None,
) -> tuple[IntArray, IntArray, IntArray]:
    """Step 4: each detection used once. Returns ``(scan, slot, support)`` of the accepted
    points: the detection each camera gives (-1: none), and how many further cameras
    support it with a merged silhouette (shared, not a detection used).

    1. *Greedy*: hypotheses sorted by scan, then best first (more cameras, then smaller mean
       squared normalised residual); each round accepts the first live hypothesis of every
       scan confirmed by ``needed`` cameras and kills those that share a detection with it.
    2. *Lending*: a killed hypothesis is accepted still when the detections left free give
       it ``needed - 1`` cameras and one more can be taken from an accepted point that has
       a camera to spare (more than ``needed``): two objects in line in one camera (a
       contact wire below its messenger) share its single detection. Only a hypothesis
       whose confirmations fit within one standard deviation on average may borrow, one
       detection at most, so points of leftovers and a coincidence (ghosts) rarely gain; the
       few that do last a scan, and tracking drops them.
    3. *Merged silhouettes*: a detection no accepted point uses, whose silhouette holds the
       image of an accepted point, images several objects in line (its centre and face
       belong to none of them). It supports every hypothesis whose image it holds: one
       with two free detections and enough such support is accepted. ``more(scans, used)``
       gives the hypotheses of the camera pairs not enumerated yet (with the covering
       pairs), for the scans that have such a silhouette and from the detections not used.
    """
    n_cameras = hypotheses.slot.shape[1]
    extra = np.maximum(hypotheses.count - 2, 1).astype(np.float64)
    badness = np.minimum(hypotheses.chi2 / extra, 999.0)
    # np.lexsort((badness, -count, scan)) in two stable sorts, the second on one small
    # integer key (scan, then more cameras first), which NumPy sorts by radix
    by_badness = np.argsort(badness, kind="stable")
    rank = hypotheses.scan * (n_cameras + 1) + (n_cameras - hypotheses.count)
    small = n * (n_cameras + 1) <= np.iinfo(np.uint16).max
    rank = rank.astype(np.uint16) if small else rank
    order = by_badness[np.argsort(rank[by_badness], kind="stable")]
    scan = hypotheses.scan[order]
    slot = hypotheses.slot[order]
    inside = hypotheses.inside[order]
    has = slot >= 0
    slot_k = np.where(has, slot, k)  # k: the camera is not in the hypothesis
    cameras = np.arange(n_cameras)[np.newaxis, :]
    owner = np.full((n, n_cameras, k + 1), -1, dtype=np.int64)
    owner_flat = owner.reshape(-1)  # a view: one index instead of three per look-up
    # each hypothesis's (scan, camera) row in the flat (n, C, K + 1) arrays, and its cells
    base = (scan[:, np.newaxis] * n_cameras + cameras) * (k + 1)
    cell = base + slot_k
    accepted_rows: list[NDArray[np.intp]] = []  # into the sorted hypotheses
    accepted_slot: list[IntArray] = []

    def accept(rows: NDArray[np.intp], use: NDArray[np.bool_]) -> None:
        first = sum(r.shape[0] for r in accepted_rows)
        index = np.arange(first, first + rows.shape[0])[:, np.newaxis]
        owner_flat[np.where(use, cell[rows], base[rows] + k)] = index
        owner[:, :, k] = -1
        accepted_rows.append(rows)
        accepted_slot.append(np.where(use, slot[rows], -1))

    def owners(rows: NDArray[np.intp]) -> IntArray:
        return owner_flat[cell[rows]]  # (g, C), -1: free

    # 1. greedy
    taken = np.zeros(scan.shape[0], dtype=bool)
    live = np.flatnonzero(hypotheses.count[order] >= needed)
    while live.shape[0]:
        chosen = live[_first_per_scan(scan[live])]
        accept(chosen, has[chosen])
        taken[chosen] = True
        live = live[~(owners(live) >= 0).any(axis=1)]

    # 2. lending
    fits_well = badness[order] <= _BORROW_MAX_CHI2
    live = np.flatnonzero(~taken & fits_well & (hypotheses.count[order] >= needed))
    while live.shape[0] and accepted_rows:
        cameras_of = (np.concatenate(accepted_slot) >= 0).sum(axis=1)
        own = owners(live)
        free = has[live] & (own < 0)
        lendable = has[live] & (own >= 0) & (cameras_of[np.maximum(own, 0)] > needed)
        eligible = (free.sum(axis=1) + 1 == needed) & lendable.any(axis=1)
        live, free, lendable, own = (v[eligible] for v in (live, free, lendable, own))
        if not live.shape[0]:
            break
        first = _first_per_scan(scan[live])
        rows = live[first]
        borrow = lendable[first] & (np.cumsum(lendable[first], axis=1) == 1)  # one camera
        slots = np.concatenate(accepted_slot)
        slots[own[first][borrow], np.nonzero(borrow)[1]] = -1
        accepted_slot[:] = [slots]
        accept(rows, free[first] | borrow)
        taken[rows] = True
        live = live[~first]

    # 3. merged silhouettes
    support = np.zeros(0, dtype=np.int64)
    if accepted_rows:
        rows_all = np.concatenate(accepted_rows)
        held = inside[rows_all]  # (a, C): candidates holding an accepted point's image
        merged = np.zeros((n, n_cameras, k + 1), dtype=bool)
        merged.reshape(-1)[base[rows_all] + np.where(held >= 0, held, k)] = True
        merged[:, :, k] = False
        merged &= owner[:, :, :] < 0  # used by no point
        scans_with = np.flatnonzero(merged.any(axis=(1, 2)))
        if more is not None and scans_with.shape[0]:
            extra = more(scans_with, owner[:, :, :k] >= 0)
            scan = np.concatenate([scan, extra.scan])
            slot = np.concatenate([slot, extra.slot])
            inside = np.concatenate([inside, extra.inside])
            has = slot >= 0
            slot_k = np.where(has, slot, k)
            base = (scan[:, np.newaxis] * n_cameras + cameras) * (k + 1)
            cell = base + slot_k
            taken = np.concatenate([taken, np.zeros(extra.scan.shape[0], dtype=bool)])
            count_all = np.concatenate([hypotheses.count[order], extra.count])
        else:
            count_all = hypotheses.count[order]

        def supporting(rows: NDArray[np.intp]) -> IntArray:
            held = inside[rows]
            return np.asarray(
                merged.reshape(-1)[base[rows] + np.where(held >= 0, held, k)].sum(axis=1),
                dtype=np.int64,
            )

        live = np.flatnonzero(~taken & (count_all >= 2))
        live = live[np.argsort(scan[live], kind="stable")]
        while live.shape[0]:
            free_all = ~(owners(live) >= 0).any(axis=1)
            eligible = free_all & (has[live].sum(axis=1) + supporting(live) >= needed)
            live = live[eligible]
            if not live.shape[0]:
                break
            first = _first_per_scan(scan[live])
            accept(live[first], has[live[first]])
            taken[live[first]] = True
            live = live[~first]
        rows_all = np.concatenate(accepted_rows)
        support = supporting(rows_all)

    if not accepted_rows:
        empty = np.zeros(0, dtype=np.int64)
        return empty, np.zeros((0, n_cameras), dtype=np.int64), empty
    rows_all = np.concatenate(accepted_rows)
    slots = np.concatenate(accepted_slot)
    by_scan = np.argsort(scan[rows_all], kind="stable")
    return (
        scan[rows_all][by_scan].astype(np.int64),
        slots[by_scan].astype(np.int64),
        support[by_scan],
    )


def match(
    cameras: Sequence[LineScanCamera],
    candidates: Candidates,
    sigma_px: FloatArray,
    config: MatchConfig | None = None,
) -> Matches:
    """Match candidates across cameras and triangulate the confirmed points.

    Parameters
    ----------
    cameras : sequence of LineScanCamera, length C
        The rig's cameras, in the order of the candidates' camera axis.
    candidates : Candidates
        Padded candidates, ``(n, C, K)`` (:func:`pad_candidates`).
    sigma_px : ndarray, shape (C,)
        Standard deviation of each camera's candidate centres [px] (:func:`camera_sigmas_px`).
    config : MatchConfig, optional
        Settings; defaults to ``MatchConfig()``.

    Returns
    -------
    Matches
        Sorted by scan; within a scan in the order the conflicts were resolved (best first).
    """
    config = config or MatchConfig()
    n, n_cameras, k = candidates.shape
    if len(cameras) != n_cameras:
        raise ValueError(f"{len(cameras)} cameras for candidates of {n_cameras}")
    if n_cameras < 2:
        raise ValueError("matching needs two cameras at least")
    geometry = [_Geometry.of(camera) for camera in cameras]
    span = 4.0 * max(camera.pixels for camera in cameras)
    # ideal centres and silhouette edges, (3, n, C, K): one undistortion per camera
    observed = np.stack([candidates.centre_px, candidates.left_px, candidates.right_px])
    ideal = np.empty(observed.shape)
    for c, camera in enumerate(cameras):
        ideal[:, :, c, :] = _undistort(camera, observed[:, :, c, :])
    u, left, right = ideal
    needed = config.cameras_needed(n_cameras)
    every_pair = list(itertools.combinations(range(n_cameras), 2))
    pairs = _covering_pairs(geometry, needed) if config.covering_pairs else every_pair
    others = [pair for pair in every_pair if pair not in pairs]
    polarity = candidates.polarity
    hypotheses = _enumerate(
        geometry, u, (left, right), polarity, sigma_px, config, span, needed, pairs
    )

    def more(scans: IntArray, used: NDArray[np.bool_]) -> _Hypotheses:
        """Hypotheses of the other pairs from the unused detections of some scans."""
        free_u = np.where(used[scans], np.nan, u[scans])
        found = _enumerate(
            geometry,
            free_u,
            (left[scans], right[scans]),
            polarity[scans],
            sigma_px,
            config,
            span,
            needed,
            others,
        )
        return replace(found, scan=scans[found.scan])

    use_more = more if (config.support_merged and others) else None
    scan, slot, support = _resolve(hypotheses, n, k, needed, use_more)  # (m,), (m, C), (m,)
    matches = _triangulate_matches(cameras, candidates, scan, slot, sigma_px, config, needed)
    matches = replace(matches, cameras=matches.cameras + support)
    if not (config.two_view and needed > 2):
        return _separate(matches, config.min_separation_mm)
    # step 6: two-view points of the detections left unused that saw a face, in scans that
    # have some in two cameras at least (a wire missed by one camera while another is blind)
    used = np.zeros(u.shape, dtype=bool)
    cameras_index = np.broadcast_to(np.arange(n_cameras), slot.shape)
    used[
        np.broadcast_to(scan[:, np.newaxis], slot.shape)[slot >= 0],
        cameras_index[slot >= 0],
        slot[slot >= 0],
    ] = True
    # only detections with a face can make a two-view point (below)
    with_face = np.isfinite(candidates.face_left_px) & np.isfinite(candidates.face_right_px)
    free_u = np.where(used | ~with_face, np.nan, u)
    rows = np.flatnonzero(np.isfinite(free_u).any(axis=2).sum(axis=1) >= 2)
    if not rows.shape[0]:
        return _separate(matches, config.min_separation_mm)
    pairs_of = _enumerate(
        geometry,
        free_u[rows],
        (left[rows], right[rows]),
        polarity[rows],
        sigma_px,
        config,
        span,
        2,
        every_pair,
    )
    only_two = pairs_of.count == 2
    two = _triangulate_matches(
        cameras,
        candidates,
        rows[pairs_of.scan[only_two]],
        pairs_of.slot[only_two],
        sigma_px,
        config,
        2,
    )
    # only from the worn face's edges seen by both: the wire's centre at night is that of
    # its lit part, which differs between cameras by millimetres (a third camera would
    # catch it, two cannot)
    two = two.take(two.from_face)
    two = replace(two, verified=np.zeros(two.count, dtype=bool))
    merged = Matches(
        **{
            f: np.concatenate([getattr(matches, f), getattr(two, f)])
            for f in Matches.__dataclass_fields__
        }
    )
    return _separate(merged.take(np.argsort(merged.scan, kind="stable")), config.min_separation_mm)


def _separate(matches: Matches, min_separation_mm: float) -> Matches:
    """Drop the weaker of two points of a scan closer than ``min_separation_mm``.

    Two wires that close touch, and then no camera tells them apart: two points there are
    one wire seen twice, once through a merged silhouette's centre or face. The stronger
    is kept: verified first, then more cameras, then the smaller reprojection RMS.
    ``matches`` is sorted by scan.
    """
    m = matches.count
    if m < 2:
        return matches
    # np.lexsort((rms, -cameras, ~verified, scan)) in two stable sorts, the second on one
    # integer key, which NumPy sorts by radix when it fits 16 bits
    by_rms = np.argsort(matches.reprojection_rms_px, kind="stable")
    most = int(matches.cameras.max())
    rank = (matches.scan * 2 + ~matches.verified) * (most + 1) + (most - matches.cameras)
    if int(rank.max()) <= np.iinfo(np.uint16).max:
        rank = rank.astype(np.uint16)
    order = by_rms[np.argsort(rank[by_rms], kind="stable")]
    ranked = matches.take(order)  # by scan, strongest first
    scan = ranked.scan
    start = np.searchsorted(scan, scan, side="left")
    slot = np.arange(m) - start
    width = int(slot.max()) + 1
    # for each point, the points of its scan ranked before it
    others = np.arange(width)
    before = others[np.newaxis, :] < slot[:, np.newaxis]
    index = np.minimum(start[:, np.newaxis] + others, m - 1)
    x = np.where(before, ranked.x_mm[index], np.nan)
    z = np.where(before, ranked.z_mm[index], np.nan)
    with np.errstate(invalid="ignore"):
        near = np.hypot(x - ranked.x_mm[:, np.newaxis], z - ranked.z_mm[:, np.newaxis])
        too_close = (near < min_separation_mm).any(axis=1)
    # a point dropped does not suppress others (one level: pairs, the case that occurs);
    # ranked by scan first, the points kept are in scan order
    return ranked.take(~too_close)


_UNDISTORT_STEP_PX = 0.25
"""Spacing of the undistortion table [px]: linear interpolation between its nodes is off
by ``k1``-small second-order terms, below 1e-6 px for any lens the model is meant for."""

_undistort_tables: dict[tuple[float, int, bytes], tuple[FloatArray, FloatArray]] = {}


def _undistort(camera: LineScanCamera, u_px: FloatArray) -> FloatArray:
    """``camera.undistort`` by interpolation in a table computed once per camera.

    The radial model's inverse is smooth, so a table over ``[-W/2, 3W/2]`` at
    ``_UNDISTORT_STEP_PX`` and linear interpolation give it to 1e-6 px at the cost of one
    ``np.interp``; values outside the table (and NaN padding) go through the exact inverse.
    """
    if camera.k1 == 0.0:
        return u_px.copy()
    key = (camera.k1, camera.pixels, camera.matrix.tobytes())
    table = _undistort_tables.get(key)
    if table is None:
        grid = np.arange(-0.5 * camera.pixels, 1.5 * camera.pixels, _UNDISTORT_STEP_PX)
        table = (grid, camera.undistort(grid))
        if not np.all(np.isfinite(table[1])):
            return camera.undistort(u_px)
        _undistort_tables[key] = table  # only finite tables are kept
    grid, ideal = table
    # the grid is uniform: the cell is found by arithmetic, not by a search
    position = (u_px - grid[0]) / _UNDISTORT_STEP_PX
    inside = (position >= 0.0) & (position < grid.shape[0] - 1)  # False for NaN
    cell = np.where(inside, position, 0.0).astype(np.intp)
    fraction = np.where(inside, position - cell, 0.0)
    out = np.where(inside, ideal[cell] + fraction * (ideal[cell + 1] - ideal[cell]), np.nan)
    outside = ~inside & np.isfinite(u_px)
    if np.any(outside):
        out[outside] = camera.undistort(u_px[outside])
    return np.asarray(out, dtype=np.float64)


def _put(values: FloatArray, rows: NDArray[np.intp], new: FloatArray) -> FloatArray:
    out = values.copy()
    out[rows] = new
    return out


def _pinhole(camera: LineScanCamera) -> LineScanCamera:
    """The camera without its radial term (equation 8 alone)."""
    if camera.k1 == 0.0:
        return camera
    key = (camera.name, camera.pixels, camera.matrix.tobytes())
    pinhole = _pinholes.get(key)
    if pinhole is None:  # built once per camera model (the cameras are immutable)
        pinhole = LineScanCamera(camera.name, camera.pixels, camera.matrix, 0.0)
        _pinholes[key] = pinhole
    return pinhole


_pinholes: dict[tuple[str, int, bytes], LineScanCamera] = {}


def _gather(scan: IntArray, slot: IntArray, *values: FloatArray) -> list[FloatArray]:
    """``v[scan, c, slot[:, c]]`` per camera of each ``(n, C, K)`` array of ``values``, NaN
    where ``slot`` is -1: each ``(m, C)``."""
    _, n_cameras, k = values[0].shape
    # one flat index, for all the arrays: far cheaper than three broadcast ones
    index = (scan[:, np.newaxis] * n_cameras + np.arange(n_cameras)) * k + np.maximum(slot, 0)
    missing = slot < 0
    out = []
    for v in values:
        gathered = v.reshape(-1)[index]
        gathered[missing] = np.nan
        out.append(gathered)
    return out


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

    Where a point has a camera to spare, the camera whose image lies furthest outside its
    confirmation window from the point the other cameras give (leave-one-out) is dropped
    and the point triangulated again: an outlier in one of the two cameras a hypothesis was
    built from moves the hypothesis, and the other cameras can still fall in their windows
    of it; at the least-squares point the outlier's error is shared among all the cameras.
    """
    left, right, face_left, face_right = _gather(
        scan,
        slot,
        candidates.left_px,
        candidates.right_px,
        candidates.face_left_px,
        candidates.face_right_px,
    )
    face_mid = 0.5 * (face_left + face_right)
    face_views = np.isfinite(face_mid).sum(axis=1)
    from_face = (face_views >= 2) & config.contact_from_faces
    # the contact point from the faces, else the axis from every camera's silhouette (a
    # camera's face centre lies a radius below the axis: the two are never mixed)
    u = np.where(from_face[:, np.newaxis], face_mid, 0.5 * (left + right))
    sigma = float(np.sqrt(np.mean(sigma_px**2))) if sigma_px.size else 0.1
    # on ideal coordinates, with the distortion-free twins of the cameras: the same least
    # squares (the radial term changes the pixel scale by a part in a thousand at most)
    ideal = np.stack([_undistort(camera, u[:, c]) for c, camera in enumerate(cameras)], 1)
    pinholes = [_pinhole(camera) for camera in cameras]
    result = triangulate(pinholes, ideal, sigma_px=sigma)
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
        again = triangulate(pinholes, ideal[rows], sigma_px=sigma)
        result = replace(
            result,
            **{
                name: _put(getattr(result, name), rows, getattr(again, name))
                for name in ("x_mm", "z_mm", "rms_reprojection_px", "sigma_x_mm", "sigma_z_mm")
            },
        )
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
    )


# -- the worn face ----------------------------------------------------------------------------


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
        when two cameras at least agree. 0.0 when no confirming camera saw a face (a new
        wire, or a face narrower than the features resolve, about two pixels: 0.6 mm, which
        leaves the residual thickness within 0.01 mm of the new wire's); NaN when faces were
        seen but fewer than two cameras agree (not measured).
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
    median = _row_median(per_camera)
    with np.errstate(invalid="ignore", divide="ignore"):
        agree = np.abs(per_camera - median[:, np.newaxis]) <= tolerance_mm
        weight = np.where(agree, 1.0 / resolution**2, 0.0)
        total = weight.sum(axis=1)
        combined = (weight * np.nan_to_num(per_camera)).sum(axis=1) / total
        deviation = np.where(agree, np.abs(per_camera - combined[:, np.newaxis]), 0.0)
    agreeing = agree.sum(axis=1)
    # two cameras at least must agree on a face; none seeing one is a face below resolution
    combined = np.where(agreeing >= 2, combined, np.where(faces == 0, 0.0, np.nan))
    combined = np.where(np.isfinite(x), combined, np.nan)
    spread = np.where(agreeing >= 2, deviation.max(axis=1, initial=0.0), np.nan)
    return FaceWidths(
        per_camera_mm=per_camera,
        table_ratio=ratio,
        width_mm=combined,
        spread_mm=spread,
        cameras=agreeing.astype(np.int64),
    )


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
    that chord, not to the axis (:func:`.stereo.contact_from_axis`).

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
    left, right = _gather(
        matches.scan[rows],
        matches.slot[rows],
        np.where(bright, candidates.left_px, np.nan),
        np.where(bright, candidates.right_px, np.nan),
    )
    phi = np.zeros(rows.shape[0]) if roll_rad is None else roll_rad[matches.scan[rows]]
    x, z = matches.x_mm[rows], matches.z_mm[rows]
    per_camera = np.full(left.shape, np.nan)
    for c, camera in enumerate(cameras):  # a loop per camera, not per point
        _, du_dx, du_dz = _Geometry.of(camera).project(x, z)
        along = np.abs(du_dx * np.cos(phi) + du_dz * np.sin(phi))  # px per mm
        with np.errstate(invalid="ignore", divide="ignore"):
            per_camera[:, c] = (right[:, c] - left[:, c]) / along
    chord[rows] = _row_median(per_camera)
    return chord


def _row_median(values: FloatArray) -> FloatArray:
    """Median of the finite values of each row of a narrow ``(m, C)`` array (NaN if none)."""
    ordered = np.sort(np.where(np.isfinite(values), values, np.inf), axis=1)
    count = np.isfinite(values).sum(axis=1)
    low = np.take_along_axis(ordered, np.maximum((count - 1) // 2, 0)[:, np.newaxis], 1)[:, 0]
    high = np.take_along_axis(ordered, np.maximum(count // 2, 0)[:, np.newaxis], 1)[:, 0]
    with np.errstate(invalid="ignore"):
        return np.where(count > 0, 0.5 * (low + high), np.nan)
