"""Step 4 of the package docstring: resolve conflicts so that each detection is used once."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from .candidates import (
    IntArray,
)
from .hypotheses import _Hypotheses

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
