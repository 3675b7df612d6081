"""Step 4 of the package docstring: resolve conflicts so that each detection is used once."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import FloatArray, IntArray

from .hypotheses import _Hypotheses

_BORROW_MAX_CHI2 = 1.0
"""Largest mean squared normalised residual of a hypothesis that may borrow a detection."""


def _resolve(
    hypotheses: _Hypotheses,
    n: int,
    k: int,
    needed: int,
    more: Callable[[IntArray, NDArray[np.bool_]], _Hypotheses] | None = None,
) -> tuple[IntArray, IntArray, IntArray]:
    """Step 4: each detection used once. Returns ``(scan, slot, support)`` of the accepted
    points, ``(m,)``, ``(m, C)``, ``(m,)``, by scan: the detection each camera gives (-1:
    none), and how many further cameras support it with a merged silhouette (shared, not a
    detection used). ``n`` and ``k`` are the block's scans and slots.

    1. *Greedy* (:func:`_greedy`): hypotheses sorted by scan, then best first (more cameras,
       then smaller mean squared normalised residual); each round accepts the first live
       hypothesis of every scan confirmed by ``needed`` cameras and kills those that share a
       detection with it.
    2. *Lending* (:func:`_lend`): two objects in line in one camera (a contact wire below
       its messenger) share its single detection. A killed hypothesis is accepted still
       with the detections left free when they give it ``needed`` cameras, or when they
       give it ``needed - 1`` and one more can be taken from an accepted point that has a
       camera to spare (more than ``needed``). Only a hypothesis whose confirmations fit
       within one standard deviation on average may borrow, one detection at most, so
       points of leftovers and a coincidence (ghosts) rarely gain; the few that do last a
       scan, and tracking drops them.
    3. *Merged silhouettes* (:func:`_merged_silhouettes`): a detection no accepted point
       uses, whose silhouette holds the image of an accepted point, images several objects
       in line (its centre and face belong to none of them). It supports every hypothesis
       whose image it holds: one with two free detections and enough such support is
       accepted. ``more(scans, used)`` gives the hypotheses of the camera pairs not
       enumerated yet (with the covering pairs), for the scans that have such a silhouette
       and from the detections not used.
    """
    n_cameras = hypotheses.slot.shape[1]
    extra = np.maximum(hypotheses.count - 2, 1).astype(np.float64)
    badness = np.minimum(hypotheses.chi2 / extra, 999.0)
    order = _rank_order(hypotheses, badness, n)
    ranked = _Ranked.of(
        hypotheses.scan[order],
        hypotheses.slot[order],
        hypotheses.inside[order],
        hypotheses.count[order],
        k,
    )
    ledger = _Ledger(n, n_cameras, k, order.shape[0])
    _greedy(ranked, ledger, needed)
    _lend(ranked, ledger, badness[order] <= _BORROW_MAX_CHI2, needed)
    if not ledger.rows:
        empty = np.zeros(0, dtype=np.int64)
        return empty, np.zeros((0, n_cameras), dtype=np.int64), empty
    ranked, support = _merged_silhouettes(ranked, ledger, needed, more)
    rows = np.concatenate(ledger.rows)
    slots = np.concatenate(ledger.slots)
    by_scan = np.argsort(ranked.scan[rows], kind="stable")
    return (
        ranked.scan[rows][by_scan].astype(np.int64),
        slots[by_scan].astype(np.int64),
        support[by_scan],
    )


def _rank_order(hypotheses: _Hypotheses, badness: FloatArray, n: int) -> NDArray[np.intp]:
    """The order of the greedy pass, ``(h,)``: by scan, then more cameras first, then
    smaller ``badness`` (the mean squared normalised residual).

    ``np.lexsort((badness, -count, scan))`` in two stable sorts, the second on one small
    integer key (scan, then more cameras first), which NumPy sorts by radix.
    """
    n_cameras = hypotheses.slot.shape[1]
    by_badness = np.argsort(badness, kind="stable")
    rank = hypotheses.scan * (n_cameras + 1) + (n_cameras - hypotheses.count)
    small = n * (n_cameras + 1) <= np.iinfo(np.uint16).max
    rank = rank.astype(np.uint16) if small else rank
    order: NDArray[np.intp] = by_badness[np.argsort(rank[by_badness], kind="stable")]
    return order


@dataclass(frozen=True)
class _Ranked:
    """Hypotheses in the greedy pass's order, ``h`` of them, with their cells in the flat
    ``(n, C, K + 1)`` arrays of detections: ``base`` each camera's row of the scan,
    ``cell`` the detection's cell (``base + K`` for a camera not in the hypothesis)."""

    scan: NDArray[np.intp]  # (h,)
    slot: IntArray  # (h, C), -1: camera not in the hypothesis
    inside: IntArray  # (h, C) unconfirming candidate whose silhouette holds it, or -1
    count: IntArray  # (h,) cameras confirming it
    has: NDArray[np.bool_]  # (h, C) slot >= 0
    base: IntArray  # (h, C)
    cell: IntArray  # (h, C)

    @classmethod
    def of(
        cls,
        scan: NDArray[np.intp],
        slot: IntArray,
        inside: IntArray,
        count: IntArray,
        k: int,
    ) -> _Ranked:
        has = slot >= 0
        n_cameras = slot.shape[1]
        base = (scan[:, np.newaxis] * n_cameras + np.arange(n_cameras)[np.newaxis, :]) * (k + 1)
        return cls(scan, slot, inside, count, has, base, base + np.where(has, slot, k))

    def extended(self, more: _Hypotheses, k: int) -> _Ranked:
        """These hypotheses followed by ``more``."""
        return _Ranked.of(
            np.concatenate([self.scan, more.scan]),
            np.concatenate([self.slot, more.slot]),
            np.concatenate([self.inside, more.inside]),
            np.concatenate([self.count, more.count]),
            k,
        )


class _Ledger:
    """The points step 4 has accepted, in the order accepted, and the detections they use.

    ``owner`` ``(n, C, K + 1)`` holds the accepted point that uses each detection, -1 where
    none (slot ``K``, a camera not in a hypothesis, stays -1); ``rows`` the accepted
    hypotheses (rows of :class:`_Ranked`), ``slots`` the detection each camera gives each
    accepted point, and ``taken`` which hypotheses were accepted ``(h,)``.
    """

    def __init__(self, n: int, n_cameras: int, k: int, hypotheses: int) -> None:
        self.k = k
        self.owner = np.full((n, n_cameras, k + 1), -1, dtype=np.int64)
        self._owner_flat = self.owner.reshape(-1)  # a view: one index, not three, per look-up
        self.rows: list[NDArray[np.intp]] = []
        self.slots: list[IntArray] = []
        self.taken = np.zeros(hypotheses, dtype=bool)

    def accept(self, ranked: _Ranked, rows: NDArray[np.intp], use: NDArray[np.bool_]) -> None:
        """Accept hypotheses ``rows`` ``(g,)`` with the detections of the cameras ``use``."""
        first = sum(r.shape[0] for r in self.rows)
        index = np.arange(first, first + rows.shape[0])[:, np.newaxis]
        self._owner_flat[np.where(use, ranked.cell[rows], ranked.base[rows] + self.k)] = index
        self.owner[:, :, self.k] = -1
        self.rows.append(rows)
        self.slots.append(np.where(use, ranked.slot[rows], -1))
        self.taken[rows] = True

    def owners(self, ranked: _Ranked, rows: NDArray[np.intp]) -> IntArray:
        """The accepted point using each detection of hypotheses ``rows``, ``(g, C)``; -1: free."""
        owners: IntArray = self._owner_flat[ranked.cell[rows]]
        return owners

    def take_back(self, points: IntArray, cameras: NDArray[np.intp]) -> None:
        """Accepted points ``points`` no longer use the detections of ``cameras``, ``(g,)``."""
        slots = np.concatenate(self.slots)
        slots[points, cameras] = -1
        self.slots[:] = [slots]


def _first_per_scan(scan: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Mask of the first entry of each run of equal values in a sorted array."""
    first = np.ones(scan.shape[0], dtype=bool)
    first[1:] = scan[1:] != scan[:-1]
    return first


def _greedy(ranked: _Ranked, ledger: _Ledger, needed: int) -> None:
    """Step 4.1: in rounds, the first live hypothesis of every scan confirmed by ``needed``
    cameras is accepted, and those sharing a detection with it die."""
    live = np.flatnonzero(ranked.count >= needed)
    while live.shape[0]:
        chosen = live[_first_per_scan(ranked.scan[live])]
        ledger.accept(ranked, chosen, ranked.has[chosen])
        live = live[~(ledger.owners(ranked, live) >= 0).any(axis=1)]


def _lend(ranked: _Ranked, ledger: _Ledger, may_borrow: NDArray[np.bool_], needed: int) -> None:
    """Step 4.2: a hypothesis left out is accepted with the detections left free when they
    are ``needed`` (the detection it shared was one of several it had to spare), or, if it
    ``may_borrow`` ``(h,)``, with them and one detection lent by an accepted point with a
    camera to spare; in rounds, the first of every scan in each."""
    live = np.flatnonzero(~ledger.taken & (ranked.count >= needed))
    while live.shape[0] and ledger.rows:
        cameras_of = (np.concatenate(ledger.slots) >= 0).sum(axis=1)
        own = ledger.owners(ranked, live)
        has = ranked.has[live]
        free = has & (own < 0)
        alone = free.sum(axis=1) >= needed
        lendable = has & (own >= 0) & (cameras_of[np.maximum(own, 0)] > needed)
        lendable &= (may_borrow[live] & ~alone)[:, np.newaxis]
        eligible = alone | ((free.sum(axis=1) + 1 == needed) & lendable.any(axis=1))
        live, free, lendable, own = (v[eligible] for v in (live, free, lendable, own))
        if not live.shape[0]:
            break
        first = _first_per_scan(ranked.scan[live])
        borrow = lendable[first] & (np.cumsum(lendable[first], axis=1) == 1)  # one camera
        ledger.take_back(own[first][borrow], np.nonzero(borrow)[1])
        ledger.accept(ranked, live[first], free[first] | borrow)
        live = live[~first]


def _merged_silhouettes(
    ranked: _Ranked,
    ledger: _Ledger,
    needed: int,
    more: Callable[[IntArray, NDArray[np.bool_]], _Hypotheses] | None,
) -> tuple[_Ranked, IntArray]:
    """Step 4.3: hypotheses of two free detections at least, in scan order, accepted where
    the merged silhouettes holding their images bring them to ``needed`` cameras, in rounds.

    Returns the hypotheses with those of ``more`` appended (``ledger.rows`` index them) and
    the support of each accepted point, ``(m,)`` in the ledger's order.
    """
    k = ledger.k
    accepted = np.concatenate(ledger.rows)
    held = ranked.inside[accepted]  # (a, C): candidates holding an accepted point's image
    merged = np.zeros(ledger.owner.shape, dtype=bool)
    merged.reshape(-1)[ranked.base[accepted] + np.where(held >= 0, held, k)] = True
    merged[:, :, k] = False
    merged &= ledger.owner < 0  # used by no point
    scans_with = np.flatnonzero(merged.any(axis=(1, 2)))
    if more is not None and scans_with.shape[0]:
        extra = more(scans_with, ledger.owner[:, :, :k] >= 0)
        ranked = ranked.extended(extra, k)
        ledger.taken = np.concatenate([ledger.taken, np.zeros(extra.scan.shape[0], dtype=bool)])

    def supporting(rows: NDArray[np.intp]) -> IntArray:
        held = ranked.inside[rows]
        return np.asarray(
            merged.reshape(-1)[ranked.base[rows] + np.where(held >= 0, held, k)].sum(axis=1),
            dtype=np.int64,
        )

    live = np.flatnonzero(~ledger.taken & (ranked.count >= 2))
    live = live[np.argsort(ranked.scan[live], kind="stable")]
    while live.shape[0]:
        free_all = ~(ledger.owners(ranked, live) >= 0).any(axis=1)
        eligible = free_all & (ranked.has[live].sum(axis=1) + supporting(live) >= needed)
        live = live[eligible]
        if not live.shape[0]:
            break
        first = _first_per_scan(ranked.scan[live])
        ledger.accept(ranked, live[first], ranked.has[live[first]])
        live = live[~first]
    return ranked, supporting(np.concatenate(ledger.rows))
