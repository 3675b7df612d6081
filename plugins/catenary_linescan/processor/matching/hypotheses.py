"""Steps 2-3 of the package docstring: enumerate the candidate points of camera pairs and
verify them in the other cameras."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .candidates import (
    FloatArray,
)
from .config import MatchConfig
from .geometry import _Geometry, _line_coefficients


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
