"""The matching's steps in order (:func:`match`), with the two-view points (step 6) and the
separation of points one wire seen twice (step 7)."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import FloatArray, IntArray
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.triangulation import triangulate

from .candidates import Candidates
from .config import MatchConfig
from .geometry import _Geometry, _pinhole, _undistort
from .hypotheses import _covering_pairs, _enumerate, _Hypotheses
from .resolve import _resolve
from .triangulate import _PROFILE_SPREAD, Matches, _edges, _image_points, _triangulate_matches


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
    matches = _match(cameras, candidates, sigma_px, config)
    if not candidates.outline_side.any():  # the radius moves no image: no need
        return matches
    measured = matches.radius_mm[np.isfinite(matches.radius_mm)]
    if measured.shape[0]:
        radius = float(np.median(measured))
        if abs(radius - config.wire_radius_mm) > _RADIUS_AGAIN_MM:
            matches = _match(cameras, candidates, sigma_px, replace(config, wire_radius_mm=radius))
    return matches


_RADIUS_AGAIN_MM = 0.1
"""The matching is done again with the wire's radius that step 5 measured in the block (the
median of its points': :func:`.triangulate._outline_axes`, :func:`.triangulate._silhouette_radii`)
where it differs from the one assumed by more than this:
candidates whose outline shows on one side only are imaged at the axis a radius inward of
it, and a radius a millimetre off keeps a third camera from confirming their points."""


def _match(
    cameras: Sequence[LineScanCamera],
    candidates: Candidates,
    sigma_px: FloatArray,
    config: MatchConfig,
) -> Matches:
    """:func:`match` with the wire's radius ``config.wire_radius_mm``."""
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
    polarity, outline = candidates.polarity, candidates.outline_side
    hypotheses = _enumerate(
        geometry, u, (left, right), polarity, outline, sigma_px, config, span, needed, pairs
    )
    # a camera's centre is its face's where it saw one (the contact point), else its
    # silhouette's middle (a dark one's is the axis, a radius above): in scans where some
    # cameras saw a face and others with candidates none, points are also sought by the
    # middles of the dark silhouettes (a lit part's middle, at night or behind the filter,
    # is no axis)
    with_face = np.isfinite(candidates.face_left_px) & np.isfinite(candidates.face_right_px)
    face_seen: NDArray[np.bool_] = np.any(with_face, axis=2)  # (n, C)
    faceless: NDArray[np.bool_] = np.any(np.isfinite(u), axis=2) & ~face_seen
    mixed = np.flatnonzero(np.any(face_seen, axis=1) & np.any(faceless, axis=1))
    if needed > 2 and mixed.shape[0]:
        dark = candidates.polarity[mixed] < 0
        middles = np.where(dark, 0.5 * (left[mixed] + right[mixed]), np.nan)
        edges = (left[mixed], right[mixed])
        axes = _enumerate(
            geometry,
            middles,
            edges,
            polarity[mixed],
            outline[mixed],
            sigma_px,
            config,
            span,
            needed,
            pairs,
        )
        hypotheses = _Hypotheses.concatenate([hypotheses, replace(axes, scan=mixed[axes.scan])])
    if needed == 2:
        hypotheses = _two_view_agreement(cameras, candidates, hypotheses, sigma_px, config)

    def more(scans: IntArray, used: NDArray[np.bool_]) -> _Hypotheses:
        """Hypotheses of the other pairs from the unused detections of some scans."""
        free_u = np.where(used[scans], np.nan, u[scans])
        found = _enumerate(
            geometry,
            free_u,
            (left[scans], right[scans]),
            polarity[scans],
            outline[scans],
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
        return _separate(matches, config)
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
    free_u = np.where(used | ~with_face, np.nan, u)
    rows = np.flatnonzero(np.isfinite(free_u).any(axis=2).sum(axis=1) >= 2)
    if not rows.shape[0]:
        return _separate(matches, config)
    pairs_of = _enumerate(
        geometry,
        free_u[rows],
        (left[rows], right[rows]),
        polarity[rows],
        outline[rows],
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
    return _separate(merged.take(np.argsort(merged.scan, kind="stable")), config)


_FACE_MISMATCH = 9.0
"""Added to the squared normalised residual of a two-camera point where one camera sees a
worn face and the other none: a face shows to every camera below the wire (three standard
deviations)."""


def _two_view_agreement(
    cameras: Sequence[LineScanCamera],
    candidates: Candidates,
    hypotheses: _Hypotheses,
    sigma_px: FloatArray,
    config: MatchConfig,
) -> _Hypotheses:
    """Where two cameras are enough (a rig of two), score how well the two images of each
    hypothesis of two agree on what they see, in place of the third camera's residual: two
    rays always meet, and a scan's detections pair up in several ways that all intersect.

    ``chi2`` gains the squared difference of the two silhouettes' widths across the rays at
    the point [mm] over its standard deviation (each edge's ``sigma_px``, and
    :data:`.triangulate._PROFILE_SPREAD` of the width for a grooved profile seen from two
    sides), and :data:`_FACE_MISMATCH` where one camera sees a face and the other none. The
    wire and its messenger are the pairing whose widths agree and whose faces match; the
    ghosts of one camera's wire with the other's messenger are not."""
    two = np.flatnonzero(hypotheses.count == 2)
    if not two.shape[0]:
        return hypotheses
    left, right, face_left, face_right = _edges(
        candidates, hypotheses.scan[two], hypotheses.slot[two]
    )
    pinholes = [_pinhole(camera) for camera in cameras]
    _, ideal = _image_points(cameras, left, right, face_left, face_right, config)
    point = triangulate(pinholes, ideal)
    width_mm = np.full(left.shape, np.nan)
    sigma_mm = np.full(left.shape, np.nan)
    for c, camera in enumerate(pinholes):  # a loop per camera, not per point
        _, du_dx, du_dz = _Geometry.of(camera).project(point.x_mm, point.z_mm)
        with np.errstate(invalid="ignore", divide="ignore"):
            px_per_mm = np.hypot(du_dx, du_dz)
            width_mm[:, c] = (right[:, c] - left[:, c]) / px_per_mm
            sigma_mm[:, c] = np.sqrt(2.0) * sigma_px[c] / px_per_mm
    seen = np.isfinite(width_mm)
    width = np.where(seen, width_mm, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        difference = width.max(axis=1) - width.min(axis=1)
        variance = np.where(seen, sigma_mm, 0.0) ** 2
        variance = variance.sum(axis=1) + (_PROFILE_SPREAD * width.max(axis=1)) ** 2
        added = np.where(seen.sum(axis=1) == 2, difference**2 / variance, 0.0)
    faces = (np.isfinite(face_left) & np.isfinite(face_right) & seen).sum(axis=1)
    added += np.where((faces == 1) & (seen.sum(axis=1) == 2), _FACE_MISMATCH, 0.0)
    chi2 = hypotheses.chi2.copy()
    chi2[two] += np.nan_to_num(added, nan=_FACE_MISMATCH)
    return replace(hypotheses, chi2=chi2)


def _separate(matches: Matches, config: MatchConfig) -> Matches:
    """Drop the weaker of two points of a scan closer than ``min_separation_mm``, unless they
    lie side by side, level, ``level_separation_mm`` or more apart across.

    Two wires that close touch, and then no camera tells them apart: two points there are
    one wire seen twice, once through a merged silhouette's centre or face, or the wire and
    what rests on it (a crossing's pipe). But a turnout's wires meet at one height: two
    verified points side by side, a height apart under half their distance across, are two
    wires once their axes are ``level_separation_mm`` apart (the widest wire and the blur:
    each camera sees them apart), or ``min_wire_width_mm`` where both were located by their
    faces (two faces the cameras saw apart; level wires lie no closer); two-view points there
    are as likely the ghosts of both. The stronger is kept: verified first, then more
    cameras, then the smaller reprojection RMS.
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
    across = np.abs(x - ranked.x_mm[:, np.newaxis])
    height = np.abs(z - ranked.z_mm[:, np.newaxis])
    verified = ranked.verified[:, np.newaxis] & ranked.verified[index]
    faces = ranked.from_face[:, np.newaxis] & ranked.from_face[index]
    apart = np.where(faces, config.min_wire_width_mm, config.level_separation_mm)
    with np.errstate(invalid="ignore"):
        side_by_side = (across >= apart) & (height < 0.5 * across)
        side_by_side &= verified
        near = np.hypot(across, height) < config.min_separation_mm
        too_close = np.asarray((near & ~side_by_side).any(axis=1))
    # a point dropped does not suppress others (one level: pairs, the case that occurs);
    # ranked by scan first, the points kept are in scan order
    return ranked.take(~too_close)
