"""Steps 2-3 of the package docstring: enumerate the candidate points of camera pairs and
verify them in the other cameras."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import FloatArray

from .config import MatchConfig
from .geometry import _Geometry, _outline_axis


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

    @classmethod
    def empty(cls, cameras: int) -> _Hypotheses:
        none = np.zeros((0, cameras), dtype=np.int64)
        return cls(np.zeros(0, np.intp), none, np.zeros(0, np.int64), none.copy(), np.zeros(0))

    @classmethod
    def concatenate(cls, parts: Sequence[_Hypotheses]) -> _Hypotheses:
        return cls(
            np.concatenate([p.scan for p in parts]),
            np.concatenate([p.slot for p in parts]),
            np.concatenate([p.count for p in parts]),
            np.concatenate([p.inside for p in parts]),
            np.concatenate([p.chi2 for p in parts]),
        )


_ENUMERATE_GROUP_ROWS = 1024
"""Scans times pairs above which :func:`_enumerate` takes the camera pairs one at a time:
with few scans (the leftovers' passes) all pairs at once save NumPy calls, a microsecond or
so each however few the rows; with many, one pair's arrays stay in the cache and its
cameras' coefficients are scalars."""


def _enumerate(
    geometry: Sequence[_Geometry],
    u: FloatArray,
    silhouette: tuple[FloatArray, FloatArray],
    polarity: NDArray[np.int8],
    outline: NDArray[np.int8],
    sigma: FloatArray,
    config: MatchConfig,
    span: float,
    needed: int,
    pairs: Sequence[tuple[int, int]],
) -> _Hypotheses:
    """Steps 2-3 of the package docstring for the given camera pairs.

    One kernel (:func:`_hypotheses`) on a group of pairs, vectorised over the pairs as well
    as the scans: all the pairs at once where the scans are few, one pair at a time above
    ``_ENUMERATE_GROUP_ROWS`` scans times pairs. Either way the hypotheses come by pair,
    then scan, then the pair's slots, and are the same.

    Parameters
    ----------
    geometry : sequence of _Geometry, length C
    u : ndarray, shape (n, C, K)
        Ideal centres of the candidates [px]; NaN: none.
    silhouette : (ndarray, ndarray), each shape (n, C, K)
        Ideal left and right silhouette edges [px].
    polarity : ndarray of int8, shape (n, C, K)
    outline : ndarray of int8, shape (n, C, K)
        Which edge alone is the wire's outline (``Candidates.outline_side``): such a
        candidate's axis lies ``config.wire_radius_mm`` inward of it
        (:func:`.geometry._outline_axis`) at the point, not at its centre.
    sigma : ndarray, shape (C,)
        Each camera's centre uncertainty [px] (:func:`.candidates.camera_sigmas_px`).
    span : float
        Bound on ``|u|`` [px] for the sorted keys (:class:`_Block`).
    needed : int
        Cameras a hypothesis needs, merged silhouettes included.
    """
    n, n_cameras, _ = u.shape
    if not pairs or n == 0:
        return _Hypotheses.empty(n_cameras)
    block = _Block.of(geometry, u, silhouette, polarity, outline, sigma, span)
    if n * len(pairs) <= _ENUMERATE_GROUP_ROWS:
        return _hypotheses(block, pairs, config, needed)
    return _Hypotheses.concatenate([_hypotheses(block, [pair], config, needed) for pair in pairs])


@dataclass(frozen=True)
class _Block:
    """A block's candidates ready for the kernel: ``n`` scans, ``C`` cameras, ``K`` slots.

    ``coef`` holds each camera's ``M`` (rows 0-5), optical axis (6-7), centre (8-9) and
    centre sigma (10): ``(11, C)``. Camera-major ``(C, n, K)``: the candidates' rays
    ``p x + q z = k`` (equation 10), polarity, and which are candidates (``valid``). The
    ``sorted_*`` fields are each camera's candidates sorted along each scan's line, flat
    over ``(C, n, K)``: ``keys`` their centres clipped to ``±span``, NaN at ``1.5 span``,
    offset by ``4 span`` per scan, so that one search per camera finds the candidate
    nearest a query in its scan whatever the scans of the queries. ``side`` (camera-major,
    and sorted), ``left`` and ``right`` (camera-major) are the outline side and the
    silhouette of candidates whose outline shows on one side only (``outline``: whether any
    does).
    """

    coef: FloatArray
    p: FloatArray
    q: FloatArray
    k: FloatArray
    polarity: NDArray[np.int8]
    valid: NDArray[np.bool_]
    keys: FloatArray
    sorted_u: FloatArray
    sorted_slot: NDArray[np.intp]
    sorted_left: FloatArray
    sorted_right: FloatArray
    sorted_polarity: NDArray[np.int8]
    side: NDArray[np.int8]
    left: FloatArray
    right: FloatArray
    sorted_side: NDArray[np.int8]
    outline: bool
    span: float

    @classmethod
    def of(
        cls,
        geometry: Sequence[_Geometry],
        u: FloatArray,
        silhouette: tuple[FloatArray, FloatArray],
        polarity: NDArray[np.int8],
        outline: NDArray[np.int8],
        sigma: FloatArray,
        span: float,
    ) -> _Block:
        """The arguments of :func:`_enumerate`, arranged."""
        n, n_cameras, k = u.shape
        coef = np.array(
            [[*g.m[:2].ravel(), *g.axis[:2], *g.centre[:2]] for g in geometry],
            dtype=np.float64,
        ).T
        coef = np.concatenate([coef, np.asarray(sigma, np.float64)[np.newaxis, :]])
        m00, m01, m02, m10, m11, m12 = (v[:, np.newaxis, np.newaxis] for v in coef[:6])
        values = np.ascontiguousarray(u.transpose(1, 0, 2))
        by_camera = np.ascontiguousarray(polarity.transpose(1, 0, 2))
        by_position = np.where(np.isnan(values), np.inf, values)
        if np.all(by_position[:, :, 1:] >= by_position[:, :, :-1]):
            # the usual case (pad_candidates sorts along the line): the stable sort's order
            order = np.broadcast_to(np.arange(k), values.shape)
            flat: slice | NDArray[np.intp] = slice(None)
        else:
            order = np.argsort(by_position, axis=2, kind="stable")
            flat = (order + (np.arange(n_cameras * n) * k).reshape(n_cameras, n, 1)).ravel()
        ordered = values.ravel()[flat]
        offset = np.tile(np.repeat(np.arange(n, dtype=np.float64) * (4.0 * span), k), n_cameras)
        side = np.ascontiguousarray(outline.transpose(1, 0, 2))
        left, right = (np.ascontiguousarray(v.transpose(1, 0, 2)) for v in silhouette)
        return cls(
            coef=coef,
            p=m00 - values * m10,
            q=m01 - values * m11,
            k=values * m12 - m02,
            polarity=by_camera,
            valid=np.isfinite(values),
            keys=np.where(np.isnan(ordered), 1.5 * span, np.clip(ordered, -span, span)) + offset,
            sorted_u=ordered,
            sorted_slot=order.ravel(),
            sorted_left=silhouette[0].transpose(1, 0, 2).ravel()[flat],
            sorted_right=silhouette[1].transpose(1, 0, 2).ravel()[flat],
            sorted_polarity=by_camera.ravel()[flat],
            side=side,
            left=left,
            right=right,
            sorted_side=side.ravel()[flat],
            outline=bool(np.any(side)),
            span=span,
        )

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(n, C, K)``."""
        c, n, k = self.valid.shape
        return int(n), int(c), int(k)


_AXIS_CENTRE = slice(6, 10)
"""Rows of :class:`_Block`'s ``coef`` with the optical axis and the centre."""
_PROJECTION = [0, 1, 2, 3, 4, 5, 10]
"""Rows of :class:`_Block`'s ``coef`` with ``M`` and the sigma."""


def _per_row(table: FloatArray, pair: NDArray[np.intp], single: bool) -> list[FloatArray]:
    """Rows of ``table`` ``(r, P)`` (one column per pair of the group) for each
    combination's pair: ``(h,)`` each, or scalars for a group of one pair."""
    return [v[0] for v in table] if single else [v[pair] for v in table]


def _project(c: list[FloatArray], x: FloatArray, z: FloatArray) -> tuple[FloatArray, ...]:
    """Ideal ``u`` and its gradient ``(du/dx, du/dz)`` with ``M``'s coefficients ``c[:6]``."""
    den = c[3] * x + c[4] * z + c[5]
    u = (c[0] * x + c[1] * z + c[2]) / den
    return u, (c[0] - u * c[3]) / den, (c[1] - u * c[4]) / den


@dataclass(frozen=True)
class _PairPoints:
    """Step 2's points of a group of camera pairs, ``(h,)`` each: the pair (its index in
    the group), the scan, the two cameras' slots, the point [mm], the two rays (equation
    10's ``p, q``) and the point's polarity (either camera's that is not 0)."""

    pair: NDArray[np.intp]
    scan: NDArray[np.intp]
    slot_a: NDArray[np.intp]
    slot_b: NDArray[np.intp]
    x: FloatArray
    z: FloatArray
    pa: FloatArray
    qa: FloatArray
    pb: FloatArray
    qb: FloatArray
    polarity: NDArray[np.int8]


def _pair_points(
    block: _Block,
    pair_a: NDArray[np.intp],
    pair_b: NDArray[np.intp],
    config: MatchConfig,
) -> _PairPoints:
    """Step 2: every combination of a valid candidate of camera ``a`` with one of ``b`` in
    the same scan, triangulated (equations 9-10) and kept in front of both cameras, inside
    the plausible volume, of matching polarity. By pair, scan, ``a``'s slot and ``b``'s
    slot (the order of ``np.nonzero`` over ``K x K``)."""
    n, _, k = block.shape
    single = pair_a.shape[0] == 1
    # flat over (P, n, K): each pair's cameras a and b
    rows_a, rows_b = _pairs_of(
        block.valid[pair_a].reshape(-1, k), block.valid[pair_b].reshape(-1, k)
    )
    pa, qa, ka = (v[pair_a].ravel()[rows_a] for v in (block.p, block.q, block.k))
    pb, qb, kb = (v[pair_b].ravel()[rows_b] for v in (block.p, block.q, block.k))
    pair = np.zeros(rows_a.shape[0], np.intp) if single else rows_a // (n * k)
    ca = _per_row(block.coef[_AXIS_CENTRE, pair_a], pair, single)
    cb = _per_row(block.coef[_AXIS_CENTRE, pair_b], pair, single)
    x_lo, x_hi = config.x_range_mm
    z_lo, z_hi = config.z_range_mm
    with np.errstate(divide="ignore", invalid="ignore"):
        det = pa * qb - pb * qa
        x = (qb * ka - qa * kb) / det
        z = (pa * kb - pb * ka) / det
        if block.outline:
            # a candidate whose outline shows on one side: its axis at the point, and the
            # point again (the resolution there hardly moves with it)
            side_a = block.side[pair_a].ravel()[rows_a]
            side_b = block.side[pair_b].ravel()[rows_b]
            ma = _per_row(block.coef[:6, pair_a], pair, single)
            mb = _per_row(block.coef[:6, pair_b], pair, single)
            silhouette_a = (block.left[pair_a].ravel()[rows_a], block.right[pair_a].ravel()[rows_a])
            silhouette_b = (block.left[pair_b].ravel()[rows_b], block.right[pair_b].ravel()[rows_b])
            radius = config.wire_radius_mm
            pa, qa, ka = _outline_rays(ma, x, z, side_a, silhouette_a, radius, (pa, qa, ka))
            pb, qb, kb = _outline_rays(mb, x, z, side_b, silhouette_b, radius, (pb, qb, kb))
            det = pa * qb - pb * qa
            x = (qb * ka - qa * kb) / det
            z = (pa * kb - pb * ka) / det
        ok = (x >= x_lo) & (x <= x_hi) & (z >= z_lo) & (z <= z_hi)
        ok &= ca[0] * (x - ca[2]) + ca[1] * (z - ca[3]) > 0.0
        ok &= cb[0] * (x - cb[2]) + cb[1] * (z - cb[3]) > 0.0
    pol_a = block.polarity[pair_a].ravel()[rows_a]
    pol_b = block.polarity[pair_b].ravel()[rows_b]
    if config.match_polarity:
        ok &= (pol_a * pol_b) >= 0
    keep = np.flatnonzero(ok)
    pair, rows_a, rows_b = pair[keep], rows_a[keep], rows_b[keep]
    pol_a, pol_b = pol_a[keep], pol_b[keep]
    row = rows_a // k  # the (pair, scan) of each point
    return _PairPoints(
        pair=pair,
        scan=row - pair * n,
        slot_a=rows_a - row * k,
        slot_b=rows_b - row * k,
        x=x[keep],
        z=z[keep],
        pa=pa[keep],
        qa=qa[keep],
        pb=pb[keep],
        qb=qb[keep],
        polarity=np.where(pol_a != 0, pol_a, pol_b),
    )


def _outline_rays(
    m: list[FloatArray],
    x: FloatArray,
    z: FloatArray,
    side: NDArray[np.int8],
    silhouette: tuple[FloatArray, FloatArray],
    radius_mm: float,
    rays: tuple[FloatArray, FloatArray, FloatArray],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Equation 10's ``p, q, k`` ``rays`` with the rays of candidates whose outline shows
    on one side (``side`` not 0; ``silhouette`` their left and right edges) through their
    axis at the points ``(x, z)`` instead (:func:`.geometry._outline_axis`); ``m`` the
    cameras' ``M`` per row."""
    _, gx, gz = _project(m, x, z)
    u = _outline_axis(*silhouette, side, np.hypot(gx, gz), radius_mm)
    one_side = side != 0
    p, q, k = rays
    return (
        np.where(one_side, m[0] - u * m[3], p),
        np.where(one_side, m[1] - u * m[4], q),
        np.where(one_side, u * m[5] - m[2], k),
    )


def _pairs_of(
    valid_a: NDArray[np.bool_], valid_b: NDArray[np.bool_]
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Flat indices of every combination of a valid candidate of ``valid_a`` with one of
    ``valid_b`` in the same row (both ``(r, K)``), in the order of ``np.nonzero`` over
    ``(row, slot_a, slot_b)``."""
    k = valid_a.shape[1]
    ia = np.flatnonzero(valid_a)
    ib = np.flatnonzero(valid_b)
    count_b = np.count_nonzero(valid_b, axis=1)
    start_b = np.cumsum(count_b) - count_b
    row_a = ia // k
    reps = count_b[row_a]
    rows_a = np.repeat(ia, reps)
    ends = np.cumsum(reps)
    within = np.arange(rows_a.shape[0]) - np.repeat(ends - reps, reps)
    rows_b = ib[np.repeat(start_b[row_a], reps) + within]
    return rows_a, rows_b


def _hypotheses(
    block: _Block, group: Sequence[tuple[int, int]], config: MatchConfig, needed: int
) -> _Hypotheses:
    """Steps 2-3 for a group of camera pairs: each pair's points (:func:`_pair_points`)
    re-projected into the other cameras and verified by the candidate nearest there.

    Each row's cameras' coefficients are gathered per row (scalars for a group of one
    pair), so that the count of NumPy calls does not grow with the pairs; the arithmetic
    per row is that of one pair at a time.
    """
    n, n_cameras, k = block.shape
    pair_a = np.array([a for a, _ in group], dtype=np.intp)
    pair_b = np.array([b for _, b in group], dtype=np.intp)
    others = np.array(
        [[c for c in range(n_cameras) if c not in pair] for pair in group], dtype=np.intp
    ).reshape(len(group), n_cameras - 2)
    single = len(group) == 1
    points = _pair_points(block, pair_a, pair_b, config)
    pair, scan, x, z = points.pair, points.scan, points.x, points.z
    bounds = np.searchsorted(pair, np.arange(len(group) + 1)).tolist()
    ca = _per_row(block.coef[_PROJECTION, :][:, pair_a], pair, single)
    cb = _per_row(block.coef[_PROJECTION, :][:, pair_b], pair, single)
    h = scan.shape[0]
    # each row's column in (h, C): one column for one pair
    rows: slice | NDArray[np.intp] = slice(None) if single else np.arange(h)
    slot = np.full((h, n_cameras), -1, dtype=np.int64)
    slot[rows, int(pair_a[0]) if single else pair_a[pair]] = points.slot_a
    slot[rows, int(pair_b[0]) if single else pair_b[pair]] = points.slot_b
    hits = np.full(h, 2, dtype=np.int64)
    inside = np.full((h, n_cameras), -1, dtype=np.int64)
    held_by = np.zeros(h, dtype=np.int64)  # cameras whose candidate's silhouette holds it
    chi2 = np.zeros(h)
    keys_of = block.keys.reshape(n_cameras, n * k)
    span = block.span
    radius = config.wire_radius_mm
    offset = scan * (4.0 * span)  # of the scan's keys
    scan_start = scan * k  # the scan's first sorted position in a camera's keys
    with np.errstate(invalid="ignore", divide="ignore"):
        # gradients of u_a and u_b, for the uncertainty carried through the triangulation
        _, gax, gaz = _project(ca, x, z)
        _, gbx, gbz = _project(cb, x, z)
        # moving u_a moves the point along b's ray (qb, -pb), and vice versa
        den_a = gax * points.qb - gaz * points.pb
        den_b = gbx * points.qa - gbz * points.pa
        for j in range(n_cameras - 2):
            cam_c = int(others[0, j]) if single else others[pair, j]
            cc = _per_row(block.coef[:, others[:, j]], pair, single)
            uc, gcx, gcz = _project(cc, x, z)
            da = (gcx * points.qb - gcz * points.pb) / den_a
            db = (gcx * points.qa - gcz * points.pa) / den_b
            variance = cc[10] ** 2 + (da * ca[6]) ** 2 + (db * cb[6]) ** 2
            window = np.maximum(config.confirm_sigmas * np.sqrt(variance), config.floor_px)
            query = np.where(cc[6] * (x - cc[8]) + cc[7] * (z - cc[9]) > 0.0, uc, np.nan)
            # the nearest candidate in camera c's row of the scan
            q = np.where(np.isnan(query), 0.0, np.clip(query, -span, span)) + offset
            position = np.empty(h, dtype=np.intp)
            for p, c in enumerate(others[:, j].tolist()):
                first, last = bounds[p], bounds[p + 1]
                position[first:last] = np.searchsorted(keys_of[c], q[first:last]) + c * n * k
            # q lies within its row's keys' band and 2.5 spans clear of the others': the
            # position is in [row_start, row_start + k]
            row_start = scan_start + cam_c * (n * k)
            lower = np.maximum(position - 1, row_start)
            upper = np.minimum(position, row_start + (k - 1))
            keys = block.keys
            pick = np.where(np.abs(keys[upper] - q) < np.abs(keys[lower] - q), upper, lower)
            found_u = block.sorted_u[pick]
            if block.outline:
                side = block.sorted_side[pick]
                silhouette = block.sorted_left[pick], block.sorted_right[pick]
                axis = _outline_axis(*silhouette, side, np.hypot(gcx, gcz), radius)
                found_u = np.where(side != 0, axis, found_u)
            residual = query - found_u
            found = block.sorted_slot[pick]
            confirmed = np.abs(residual) <= window
            # the image falls inside a candidate whose centre does not confirm it: perhaps
            # a merged silhouette (step 4 decides)
            held = (query >= block.sorted_left[pick]) & (query <= block.sorted_right[pick])
            if config.match_polarity:
                same = (points.polarity * block.sorted_polarity[pick]) >= 0
                confirmed &= same
                held &= same
            slot[rows, cam_c] = np.where(confirmed, found, -1)
            hits += confirmed
            chi2 += np.where(confirmed, residual * residual / variance, 0.0)
            held &= ~confirmed
            inside[rows, cam_c] = np.where(held, found, -1)
            held_by += held
    # with two cameras confirming, merged silhouettes may still bring it to ``needed``
    possible = hits + held_by if config.support_merged else hits
    keep = np.flatnonzero(possible >= needed)
    return _Hypotheses(scan[keep], slot[keep], hits[keep], inside[keep], chi2[keep])
