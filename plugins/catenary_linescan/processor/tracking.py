"""Wire selection along the run (the paper's section 3.2, step 5): tracks and wire numbers.

The matching gives, per scan, every point three cameras agree on (and unverified points of
two, where both saw a worn face): contact wires, messengers, and in a few scans droppers,
clamps, steady arms and registration tubes. A contact wire is continuous along the track;
the fittings are not (a dropper is 5 mm thick along the track, a steady arm 26 mm, a clamp
30-50 mm), and messengers run higher. So the tracker

1. **links** the points of consecutive scans (vectorised over the block): mutual nearest
   neighbours within a tight gate (``link_mm`` plus the wire's possible slope times the
   distance travelled), which chains them into fragments (pointer jumping to each chain's
   first point); a fitting that takes the wire's place for a few scans jumps out of it;
2. **joins** fragments to the open tracks across gaps of up to ``max_gap_m`` (a missed
   detection, a clamp, a stretch where a blinded camera and a miss leave fewer than three
   views), predicting each track's end linearly (one loop step per fragment, not per point);
   a confirmed track within its gate goes before one not yet confirmed. A longer fragment
   takes a track over from a shorter one that had continued it where the wire was missed
   (a clamp's few points), and a short excursion out of the tight gate that the track comes
   back from is undone; the fragment set apart is a track of its own. A fragment of
   unverified (two-view) points only continues a track within the tight gate;
3. **confirms** a track when it spans ``min_track_m`` of track (``MIN_TRACK_M``) with points
   in ``min_coverage`` of its scans: fittings never do; a track that ends unconfirmed is
   dropped with its points;
4. **removes messengers by height** at release: a point more than ``messenger_gap_mm`` above
   the lowest confirmed track at its scan (each track's height interpolated across the scans
   where it was missed), or more than ``max_height_mm`` above the roof, is not a contact
   wire — a messenger, or a contact wire raised out of running at an overlap's end on its
   way to its anchor — nor is one more than ``RESTING_MM`` above a track within
   ``RESTING_ACROSS_MM`` across, where that track runs (a crossing's pipe on the wire, a
   wire riding over it). The contact wire is the lowest wire of its system, so a point with
   a lower wire's evidence beneath it is not reported as a contact wire either, even when
   that wire's points made no confirmed track (a worn wire scattered by daylight):
   ``LOWER_WIRE_POINTS`` verified points of no confirmed track within ``max_gap_m`` along
   the track (as far as the tracker sees ahead), more than ``messenger_gap_mm`` below the
   point's track, mark it ``selection_uncertain`` (a column of the released points): the
   selection cannot tell which wire runs there. So does a track alone in view that was last
   seen above another wire, not level with one: a messenger whose contact wire the cameras
   lost; so does a point higher than a wire that ended before it (seen over a longer stretch
   than the point's track) could have climbed since (``CONTACT_GRADIENT_MM_PER_M``), and the
   rest of its track while it stays alone: a messenger first seen, or seen with another,
   where its contact wire was lost; and a point with another track within ``CROSSING_MM``
   across at its height (a turnout's crossing: the cameras see one image of both wires,
   located between them), unless the cameras agreed on a worn face there (``face_mm``)
   and the point lies within ``CROSSING_LINE_MM`` of the line its wire's points on one side
   give, their faces as wide as its own within ``CROSSING_WIDTH_MM`` (that wire's own face,
   seen alone);
5. **numbers** each track at its first contact point (0, 1, ... in order of appearance) and
   keeps the number through the run: a track that ended up to ``reidentify_m`` before and
   near where the new one starts hands its number over;
6. **releases** the points of every scan once no undecided track could still claim it and
   ``max_gap_m`` of track beyond it has been seen (so that the result does not depend on
   how the run is cut into blocks): each :meth:`WireTracker.push` returns what is decided,
   :meth:`WireTracker.finish` the rest. A point off the line its wire's neighbours on both
   sides give (``NEIGHBOURS`` within ``NEIGHBOUR_M``) by more than the link gate and their
   own scatter is left out: a fitting's points scattered over a few scans, even where they
   broke the wire's track in two.

Everything the tracker holds back spans a few metres of track before the last block's end
(``min_track_m`` and ``max_gap_m`` twice at most), so its memory is bounded whatever the
run's length.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import FloatArray, IntArray, row_median

__all__ = [
    "MIN_TRACK_M",
    "UNCERTAIN_COLUMN",
    "TrackedPoints",
    "TrackingConfig",
    "WireTracker",
    "link_fragments",
]

UNCERTAIN_COLUMN = "selection_uncertain"
"""Column of :class:`TrackedPoints` set where the selection cannot tell that a point is the
contact wire: a lower wire's points beneath its track, its track alone in view after it
was seen above another wire, or another wire crossing it (step 4 of the module docstring)."""

LOWER_WIRE_POINTS = 5
"""Fewest verified points beneath a track that show a lower wire there (``MIN_TRACK_POINTS``:
as few as a track needs; a fitting below the contact wire does not exist, and noise is not
verified by three cameras)."""

RESTING_MM = 30.0
"""Height above a wire [mm] from which a point close across it rests on it rather than being
it: twice the thickest wire's diameter (15 mm). A wire crossing over another at a turnout
rides one diameter higher, and both are running there; two tracks of one wire whose heights
disagree (a new wire by day, located by its silhouettes) differ by less."""

RESTING_ACROSS_MM = 30.0
"""Distance across [mm] within which a point above a wire rests on it: two wire widths."""

CROSSING_MM = 20.0
"""Distance across [mm] within which two wires at one height (a turnout's crossing) make one
image in the cameras: the widest wire (15 mm) and the blur. Neither is located there."""

CROSSING_LINE_MM = 1.0
"""Farthest a point at a crossing may lie from the line its wire's points on one side give
(``x`` and ``z``) to be that wire's own [mm]: half the 2-mm accuracy of a height or a
stagger. An image of both wires lies half their distance from each: off the line of a side
whose points are one wire's, and a side that holds it and one wire's points is no line."""

CROSSING_WIDTH_MM = 0.1
"""Farthest the face widths of a crossing's point and of the points of its wire it is checked
against may differ [mm] (about 0.1 mm of residual thickness near the wear limit): where the
wires lie within a millimetre of each other, one track may hold both, whose faces differ,
or the image of both faces, wider than either."""


CONTACT_GRADIENT_MM_PER_M = 25.0
"""Steepest a contact wire's height changes along the track [mm/m]: 1:40, the steepest
gradient EN 50119 allows (at the lowest speeds)."""

MIN_TRACK_POINTS = 5
"""Fewest points of a track accepted as a wire."""

_FAR_MM = 400.0
"""Farther than this from a track's end no gate reaches [mm] (the gap gate's 20 mm + 40 mm/m
and a slope of 150 mm/m over a metre's gap stay well below)."""

UNVERIFIED_REACH_M = 0.25
"""Farthest an unverified (two-view) point may lie from its track's nearest verified point
[m]: continuity checks a point against its neighbours, not against a stretch of its own."""

REIDENTIFY_GROWTH_M = 10.0
"""Gap beyond which the re-identification gate stops growing [m] (to 460 mm by default)."""

EXCURSION_M = 0.15
"""Longest excursion of a track that is undone when the track comes back [m]: a fitting's
face (a clamp's, 30-50 mm along the track) taking the wire's place, with room."""

NEIGHBOURS = 4
"""Points of its wire on either side against which a point is checked (``_consistent``)."""

NEIGHBOUR_M = 0.3
"""Farthest a neighbour a point is checked against may lie along the track [m]: twice
``EXCURSION_M``, so that a fitting's few points have wire on both sides of them."""

MIN_TRACK_M = 0.5
"""Shortest track accepted as a wire [m]. Fittings cut by the scanning plane are short along
the track (a dropper 5 mm, a steady arm 26 mm, a dropper clamp 30 mm, a registration clamp or
tube 42-50 mm: ``reference/wire-profiles.md`` and the simulator's scene), ten times below this;
a contact wire is continuous for hundreds of metres. Half a metre is 30 scans at 60 km/h and
1000 scans/s, and 7 at 250 km/h with 5,300 scans/s, still enough to tell a wire from noise."""


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of the wire tracker (lengths along the track in m, across it in mm).

    Attributes
    ----------
    link_mm : float
        Largest jump of a wire between consecutive scans at standstill, in ``x`` and in ``z``
        [mm]: the noise of the points (tenths of a millimetre) and the body's motion in a
        millisecond, with room. A clamp or a fitting that takes the wire's place in a scan
        moves the point by more (a dropper clamp's face 6 mm up) and breaks the chain; a
        wire whose points scatter by more is joined across the breaks (``gate_mm``).
    x_mm_per_m, z_mm_per_m : float
        Extra jump per metre travelled [mm/m]: a wire's angle in plan (150 mm/m is 8.5°, a
        turnout's) and its rise (40 mm/m: a wire rising to its anchor).
    gate_mm : float
        Largest distance between a track's predicted end and a fragment that continues it
        across a gap [mm] (``x`` and ``z``), plus ``gap_gate_mm_per_m`` [mm/m] of the gap.
    max_gap_m : float
        Longest gap in a track that is bridged [m].
    min_track_m : float
        Shortest track accepted as a wire [m] (``MIN_TRACK_M``).
    min_coverage : float
        Fraction of its scans in which a track must have a point to be a wire: noise does
        not chain across gaps into a track, nor do the ghosts that two wires close together
        make in a few scans, while a worn wire that the cameras see in one scan of five (its
        face as bright as a white sky) still makes one; a wire seen less often shows
        beneath its messenger (step 4).
    messenger_gap_mm : float
        Height above the lowest contact wire from which a wire is a messenger [mm]: below the
        300 mm a messenger keeps above its contact wire at its lowest (the shortest dropper
        mid-span of the lowest systems), well above the noise of the heights. A contact wire
        raised this far above the running one is out of running.
    reidentify_m : float
        A contact wire track that ended this recently [m] (two spans: a wire raised out of
        running at an overlap can leave the view and come back) and a new one whose first
        contact point lies within ``reidentify_mm + gap_gate_mm_per_m · min(gap,
        REIDENTIFY_GROWTH_M)`` of where it ended are the same wire.
    reidentify_mm : float
        See ``reidentify_m`` [mm].
    max_height_mm : float
        Highest a contact wire runs above the roof [mm]: 1,300-2,500 mm on the paper's trains,
        at most 6,500 mm above the rail with tolerances and uplift
        (``reference/wire-profiles.md``), with room for the body's bounce. A wire higher is a
        messenger whatever lies beneath it (its contact wire unseen).
    """

    link_mm: float = 3.0
    x_mm_per_m: float = 150.0
    z_mm_per_m: float = 40.0
    gate_mm: float = 20.0
    gap_gate_mm_per_m: float = 40.0
    max_gap_m: float = 1.0
    min_track_m: float = MIN_TRACK_M
    min_coverage: float = 0.2
    messenger_gap_mm: float = 200.0
    reidentify_m: float = 100.0
    reidentify_mm: float = 60.0
    max_height_mm: float = 3000.0


@dataclass(frozen=True, eq=False)
class TrackedPoints:
    """Points released by the tracker, ``m`` rows sorted by scan, then by ``x``.

    ``scan`` is the run's scan index, ``wire`` the wire number; ``face_mm`` the face width
    pushed [mm], NaN where another wire's track runs within ``CROSSING_MM`` across at the
    point's height (a turnout's crossing: a point there that is one wire's, step 4, is that
    wire's position, but the other wire's image may border its face); ``columns`` carries
    the caller's per-point values (as pushed) through.
    """

    scan: IntArray
    wire: IntArray
    position_m: FloatArray
    x_mm: FloatArray
    z_mm: FloatArray
    face_mm: FloatArray
    columns: dict[str, NDArray[np.generic]] = field(default_factory=dict)

    @property
    def rows(self) -> int:
        return int(self.scan.shape[0])


def link_fragments(
    scan: IntArray,
    position_m: FloatArray,
    x_mm: FloatArray,
    z_mm: FloatArray,
    link_mm: float,
    x_mm_per_m: float,
    z_mm_per_m: float,
) -> IntArray:
    """Chain points of consecutive scans into fragments (step 1 of the module docstring).

    Parameters
    ----------
    scan : ndarray of int, shape (m,)
        Scan index of each point, non-decreasing.
    position_m : ndarray, shape (m,)
        Position along the track of each point's scan [m].
    x_mm, z_mm : ndarray, shape (m,)
        Roof-frame position [mm].
    link_mm : float
        Largest jump between consecutive scans at standstill, in ``x`` and in ``z`` [mm].
    x_mm_per_m, z_mm_per_m : float
        Extra jump per metre travelled in ``x`` and in ``z`` [mm/m].

    Returns
    -------
    ndarray of int, shape (m,)
        For each point the index of its fragment's first point: points of one fragment share
        it. A point links to one in the next scan when each is the other's nearest (largest
        of ``|Δx|`` and ``|Δz|`` over their gates) and both jumps are within their gates.
    """
    m = scan.shape[0]
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    first_scan = int(scan[0])
    local = scan - first_scan
    n = int(local[-1]) + 1
    start = np.searchsorted(local, np.arange(n + 1))
    slot = np.arange(m) - start[local]
    width = int(slot.max()) + 1
    index = np.full((n + 1, width), -1, dtype=np.int64)  # one empty row past the end
    index[local, slot] = np.arange(m)
    xs = np.full(index.shape, np.nan)
    zs = np.full(index.shape, np.nan)
    ps = np.full(n + 1, np.nan)
    xs[local, slot] = x_mm
    zs[local, slot] = z_mm
    ps[local] = position_m
    step = np.abs(ps[1:] - ps[:-1])[:, np.newaxis, np.newaxis]  # (n, 1, 1)
    dx = np.abs(xs[1:, np.newaxis, :] - xs[:-1, :, np.newaxis])  # (n, this, next)
    dz = np.abs(zs[1:, np.newaxis, :] - zs[:-1, :, np.newaxis])
    with np.errstate(invalid="ignore"):
        distance = np.fmax(dx / (link_mm + x_mm_per_m * step), dz / (link_mm + z_mm_per_m * step))
    distance = np.where(np.isnan(distance), np.inf, distance)
    forward = np.argmin(distance, axis=2)  # (n, this): nearest in the next scan
    backward = np.argmin(distance, axis=1)  # (n, next): nearest in this scan
    best = np.take_along_axis(distance, forward[:, :, np.newaxis], axis=2)[:, :, 0]
    mutual = np.take_along_axis(backward, forward, axis=1) == np.arange(width)[np.newaxis, :]
    link = mutual & (best <= 1.0) & (index[:-1] >= 0)
    rows, cols = np.nonzero(link)
    predecessor = np.full(m, -1, dtype=np.int64)
    predecessor[index[rows + 1, forward[rows, cols]]] = index[rows, cols]
    root = np.where(predecessor >= 0, predecessor, np.arange(m))
    while True:  # pointer jumping: log2(longest chain) rounds
        jumped = root[root]
        if np.array_equal(jumped, root):
            break
        root = jumped
    return root


@dataclass
class _Track:
    """A track being followed (internal state of :class:`WireTracker`)."""

    id: int
    start_m: float
    start_scan: int
    end_m: float
    end_scan: int
    end_x: float
    end_z: float
    points: int = 0
    slope_x: float = 0.0  # mm per m
    slope_z: float = 0.0
    confirmed: bool = False
    wire: int = -1
    # the last fragment joined (its first scan, its points, its index in the block being
    # added or -1) and the track's end before it, so that a longer fragment can take over
    last_start_scan: int = -1
    last_start_m: float = 0.0
    last_jumped: bool = False
    last_points: int = 0
    last_fragment: int = -1
    before: tuple[float, int, float, float, float, float, int] | None = None

    @property
    def span_m(self) -> float:
        """Length of track from its first point to its last [m]."""
        return self.end_m - self.start_m

    def snapshot(self) -> tuple[float, int, float, float, float, float, int]:
        return (
            self.end_m,
            self.end_scan,
            self.end_x,
            self.end_z,
            self.slope_x,
            self.slope_z,
            self.points,
        )

    def restore(self, state: tuple[float, int, float, float, float, float, int]) -> None:
        (
            self.end_m,
            self.end_scan,
            self.end_x,
            self.end_z,
            self.slope_x,
            self.slope_z,
            self.points,
        ) = state

    @property
    def length_m(self) -> float:
        return self.end_m - self.start_m


@dataclass
class _Store:
    """Points held back, columnar."""

    scan: IntArray
    position_m: FloatArray
    x_mm: FloatArray
    z_mm: FloatArray
    track: IntArray
    verified: NDArray[np.bool_]
    face_mm: FloatArray
    columns: dict[str, NDArray[np.generic]]

    _ARRAYS = ("scan", "position_m", "x_mm", "z_mm", "track", "verified", "face_mm")

    @classmethod
    def empty(cls) -> _Store:
        return cls(
            np.zeros(0, np.int64),
            np.zeros(0),
            np.zeros(0),
            np.zeros(0),
            np.zeros(0, np.int64),
            np.zeros(0, bool),
            np.zeros(0),
            {},
        )

    def append(self, other: _Store) -> None:
        for name in self._ARRAYS:
            setattr(self, name, np.concatenate([getattr(self, name), getattr(other, name)]))
        if not self.columns:
            self.columns = {k: v.copy() for k, v in other.columns.items()}
        else:
            for key in self.columns:
                self.columns[key] = np.concatenate([self.columns[key], other.columns[key]])

    def take(self, rows: NDArray[np.bool_]) -> _Store:
        """The rows where ``rows`` is true (a copy)."""
        taken = _Store.empty()
        for name in self._ARRAYS:
            setattr(taken, name, getattr(self, name)[rows])
        taken.columns = {k: v[rows] for k, v in self.columns.items()}
        return taken

    def split(self, rows: NDArray[np.bool_]) -> _Store:
        """Remove and return the rows where ``rows`` is true."""
        taken = self.take(rows)
        kept = self.take(~rows)
        for name in self._ARRAYS:
            setattr(self, name, getattr(kept, name))
        self.columns = kept.columns
        return taken


class WireTracker:
    """Streaming wire selection (module docstring): push blocks of points, get wires back."""

    def __init__(self, config: TrackingConfig | None = None) -> None:
        self.config = config or TrackingConfig()
        self._store = _Store.empty()
        self._open: dict[int, _Track] = {}  # tracks that can still grow
        self._closed: dict[int, _Track] = {}  # confirmed tracks that ended, points still held
        self._lost: list[_Track] = []  # numbered tracks that ended, for re-identification
        # per track, the scan, position, x and z of the point released last, and of the
        # verified point released last
        self._last_released: dict[int, tuple[int, float, float, float]] = {}
        self._last_verified: dict[int, tuple[int, float, float, float]] = {}
        # per wire number, the position, x, z and face width of the last NEIGHBOURS points
        # released
        self._recent: dict[int, tuple[FloatArray, ...]] = {}
        # verified points released within max_gap_m (their position, height and track): step 4
        self._behind = _Store.empty()
        self._released_m = -np.inf  # position of the last point released
        # per track, whether it was last seen above another wire (1) or level with one (-1)
        self._above: dict[int, int] = {}
        self._next_track = 0
        self._next_wire = 0
        self._last_m = -np.inf
        self._last_scan = -1
        self._columns: tuple[str, ...] | None = None

    @property
    def held_points(self) -> int:
        """Points held back (not yet released or dropped)."""
        return int(self._store.scan.shape[0])

    @property
    def wires(self) -> int:
        """Wire numbers given so far."""
        return self._next_wire

    # -- the stream --------------------------------------------------------------------------

    def push(
        self,
        scan: IntArray,
        position_m: FloatArray,
        x_mm: FloatArray,
        z_mm: FloatArray,
        columns: Mapping[str, NDArray[np.generic]] | None = None,
        *,
        verified: NDArray[np.bool_] | None = None,
        face_mm: FloatArray | None = None,
        last_scan: int | None = None,
        last_position_m: float | None = None,
    ) -> TrackedPoints:
        """Add a block's points; return the points now decided.

        Parameters
        ----------
        scan : ndarray of int, shape (m,)
            Run scan index of each point, after every scan pushed before.
        position_m : ndarray, shape (m,)
            Position along the track of each point's scan [m], non-decreasing with the scan.
        x_mm, z_mm : ndarray, shape (m,)
            Roof-frame position [mm].
        columns : mapping of str to ndarray (m, ...), optional
            Values carried through to the output (the same keys on every push).
        verified : ndarray of bool, shape (m,), optional
            Which points the matching verified (default: all). A chain of unverified points
            (two cameras only) never starts a track: it only continues one whose end
            predicts it within the tight link gate, and is dropped otherwise.
        face_mm : ndarray, shape (m,), optional
            Width of the worn face the cameras agreed on at each point [mm] (0 or NaN: none;
            default: none): one wire's own, at a turnout's crossing, where the point lies on
            its wire's line (step 4).
        last_scan, last_position_m : optional
            The block's last scan and its position, when it may have no point there: the
            tracker then knows how far the run has gone.

        Returns
        -------
        TrackedPoints
            The points of the contact wires that are now decided.
        """
        scan = np.asarray(scan, dtype=np.int64)
        position = np.asarray(position_m, dtype=np.float64)
        x = np.asarray(x_mm, dtype=np.float64)
        z = np.asarray(z_mm, dtype=np.float64)
        cols = {k: np.asarray(v) for k, v in (columns or {}).items()}
        if self._columns is None:
            self._columns = tuple(cols)
        elif tuple(cols) != self._columns:
            raise ValueError(f"columns {tuple(cols)} differ from the first push's {self._columns}")
        checked = (
            np.ones(scan.shape, dtype=bool) if verified is None else np.asarray(verified, bool)
        )
        face = np.zeros(scan.shape) if face_mm is None else np.asarray(face_mm, np.float64)
        order = np.lexsort((x, scan))
        scan, position, x, z = scan[order], position[order], x[order], z[order]
        checked, face = checked[order], face[order]
        cols = {k: v[order] for k, v in cols.items()}
        if scan.shape[0] and scan[0] <= self._last_scan:
            raise ValueError(f"scan {scan[0]} pushed after scan {self._last_scan}")
        if scan.shape[0]:
            self._add(scan, position, x, z, checked, face, cols)
        if last_scan is not None:
            self._last_scan = max(self._last_scan, int(last_scan))
        if last_position_m is not None:
            self._last_m = max(self._last_m, float(last_position_m))
        self._close_stale()
        return self._release(final=False)

    def finish(self) -> TrackedPoints:
        """Decide every track still open and return the rest of the points."""
        for track in list(self._open.values()):
            self._end(track)
        return self._release(final=True)

    # -- steps -------------------------------------------------------------------------------

    def _add(
        self,
        scan: IntArray,
        position: FloatArray,
        x: FloatArray,
        z: FloatArray,
        verified: NDArray[np.bool_],
        face_mm: FloatArray,
        cols: dict[str, NDArray[np.generic]],
    ) -> None:
        config = self.config
        root = link_fragments(
            scan, position, x, z, config.link_mm, config.x_mm_per_m, config.z_mm_per_m
        )
        fragments, fragment_of, sizes = np.unique(root, return_inverse=True, return_counts=True)
        members = np.argsort(fragment_of, kind="stable")
        bounds = np.concatenate([[0], np.cumsum(sizes)])
        track_of_fragment = np.full(fragments.shape[0], -1, dtype=np.int64)
        for open_track in self._open.values():
            open_track.last_fragment = -1
        # by first scan, longest first: a wire's fragment claims its track before a clamp's
        for f in np.lexsort((-sizes, scan[fragments])):  # one step per fragment, not per point
            rows = members[bounds[f] : bounds[f + 1]]
            track = self._join(
                rows, scan, position, x, z, f, track_of_fragment, bool(verified[rows].any())
            )
            track_of_fragment[f] = -1 if track is None else track.id
        track_id = track_of_fragment[fragment_of]
        kept = track_id >= 0  # unverified chains that continued no track are dropped
        self._store.append(
            _Store(
                scan[kept],
                position[kept],
                x[kept],
                z[kept],
                track_id[kept],
                verified[kept],
                face_mm[kept],
                {k: v[kept] for k, v in cols.items()},
            )
        )
        self._last_scan = max(self._last_scan, int(scan[-1]))
        self._last_m = max(self._last_m, float(position[-1]))
        self._merge_duplicates()
        for track in self._open.values():
            if not track.confirmed and self._long_enough(track):
                track.confirmed = True

    def _merge_duplicates(self) -> None:
        """Merge open tracks that end together at one place: one wire followed twice.

        When a wrong point breaks a wire's chain, the wire's next points may start a second
        track while the first is still open, and the two then take its points in turns. Two
        tracks whose ends are within ``link_mm`` and ``max_gap_m`` of each other are one: the
        younger's points join the older (which keeps its number, or takes the younger's).
        Two wires that touch (a crossing) are merged too, and part after it; no camera
        separates them there anyway.
        """
        config = self.config
        tracks = sorted(self._open.values(), key=lambda t: t.id)
        if len(tracks) < 2:
            return
        ends = np.array([[t.end_m, t.end_x, t.end_z] for t in tracks])
        close = (
            (np.abs(ends[:, None, 0] - ends[None, :, 0]) <= config.max_gap_m)
            & (np.abs(ends[:, None, 1] - ends[None, :, 1]) <= config.link_mm)
            & (np.abs(ends[:, None, 2] - ends[None, :, 2]) <= config.link_mm)
        )
        older, younger = np.nonzero(np.triu(close, k=1))
        merged: set[int] = set()
        for i, j in zip(older.tolist(), younger.tolist(), strict=True):
            keep, gone = tracks[i], tracks[j]
            if keep.id in merged or gone.id in merged:
                continue
            if keep.wire >= 0 and gone.wire >= 0:
                continue  # two numbered wires: leave them (their numbers are out already)
            self._store.track[self._store.track == gone.id] = keep.id
            points = keep.points + gone.points
            if gone.end_scan > keep.end_scan:
                keep.restore(gone.snapshot())
                keep.before = None
            keep.points = points
            keep.start_m = min(keep.start_m, gone.start_m)
            keep.start_scan = min(keep.start_scan, gone.start_scan)
            keep.confirmed = keep.confirmed or gone.confirmed
            if keep.wire < 0:
                keep.wire = gone.wire
            del self._open[gone.id]
            merged.add(gone.id)

    def _long_enough(self, track: _Track) -> bool:
        config = self.config
        covered = track.points / (track.end_scan - track.start_scan + 1)
        return (
            track.length_m >= config.min_track_m
            and track.points >= MIN_TRACK_POINTS
            and covered >= config.min_coverage
        )

    def _join(
        self,
        rows: IntArray,
        scan: IntArray,
        position: FloatArray,
        x: FloatArray,
        z: FloatArray,
        fragment: int,
        track_of_fragment: IntArray,
        verified: bool = True,
    ) -> _Track | None:
        """Attach one fragment to the open track that predicts it best, or start a track.

        A fragment of unverified points only continues a track within the tight link gate
        of its end, and starts none (None).

        Two cases undo the track's last fragment ``F`` and give the track to this one, ``G``,
        with ``F`` set apart as a track of its own (short, it is dropped):

        - *take-over*: ``F`` overlaps ``G`` in scans and is shorter (a clamp's few points had
          continued the wire where it was missed, and the wire's own points come back);
        - *excursion*: ``F`` is short (``EXCURSION_M``), jumped out of the tight link gate
          of the track's end before it, and ``G`` comes back within that gate of it (a
          fitting's face took the wire's place for a few scans).
        """
        config = self.config
        p0, x0, z0 = float(position[rows[0]]), float(x[rows[0]]), float(z[rows[0]])
        s0 = int(scan[rows[0]])

        def offset(
            state: tuple[float, int, float, float, float, float, int],
        ) -> tuple[float, float, float]:
            end_m, end_scan, end_x, end_z, sx, sz, _ = state
            gap = p0 - end_m
            if end_scan >= s0 or gap > config.max_gap_m:
                return np.inf, np.inf, np.inf
            gap = max(gap, 0.0)
            return abs(end_x + sx * gap - x0), abs(end_z + sz * gap - z0), gap

        def fit(state: tuple[float, int, float, float, float, float, int]) -> float:
            """Distance to the prediction over the loose (gap) gate; inf beyond it."""
            dx, dz, gap = offset(state)
            distance = max(dx, dz) / (config.gate_mm + config.gap_gate_mm_per_m * gap)
            return distance if distance <= 1.0 else np.inf

        def linked(state: tuple[float, int, float, float, float, float, int]) -> bool:
            """Whether the fragment continues the state within the tight link gate."""
            dx, dz, gap = offset(state)
            return bool(
                dx <= config.link_mm + config.x_mm_per_m * gap
                and dz <= config.link_mm + config.z_mm_per_m * gap
            )

        if not verified:
            best: _Track | None = None
            best_distance = np.inf
            for track in self._open.values():
                if (
                    track.end_m < p0 - config.max_gap_m
                    or max(abs(track.end_x - x0), abs(track.end_z - z0)) > _FAR_MM
                ):
                    continue
                now = track.snapshot()
                if linked(now) and fit(now) < best_distance:
                    best, best_distance = track, fit(now)
            if best is None:
                return None
            return self._extend(best, rows, scan, position, x, z, fragment, jumped=False)

        best = None
        best_distance = np.inf
        detach = False
        oldest = p0 - config.max_gap_m
        for track in self._open.values():
            # quick rejections: ended too long ago, or far away (no gate reaches that far)
            if track.end_m < oldest or max(abs(track.end_x - x0), abs(track.end_z - z0)) > _FAR_MM:
                continue
            now = track.snapshot()
            before = track.before
            undo = before is not None and (
                (
                    track.last_start_scan <= s0 <= track.end_scan
                    and track.last_points < rows.shape[0]
                )
                or (
                    track.last_jumped
                    and track.end_m - track.last_start_m <= EXCURSION_M
                    and linked(before)
                    and not linked(now)
                )
            )
            distance = fit(before) if undo and before is not None else fit(now)
            # a confirmed wire within its gate continues before a fragment not yet confirmed
            # (a fitting's point set apart from it)
            distance += 0.0 if track.confirmed else 1.0
            if distance < best_distance:
                best, best_distance, detach = track, distance, undo
        if best is not None and detach:
            self._detach(best, track_of_fragment)
        jumped = best is not None and not linked(best.snapshot())
        if best is None:
            best = _Track(self._next_track, p0, s0, p0, s0, x0, z0)
            self._next_track += 1
            self._open[best.id] = best
        return self._extend(best, rows, scan, position, x, z, fragment, jumped=jumped)

    def _extend(
        self,
        best: _Track,
        rows: IntArray,
        scan: IntArray,
        position: FloatArray,
        x: FloatArray,
        z: FloatArray,
        fragment: int,
        *,
        jumped: bool,
    ) -> _Track:
        """Append a fragment to a track: its end, its slope, what undoing it needs."""
        p0, s0 = float(position[rows[0]]), int(scan[rows[0]])
        best.before = best.snapshot() if best.points else None
        best.last_jumped = jumped
        best.last_start_m = p0
        best.last_start_scan = s0
        best.last_points = int(rows.shape[0])
        best.last_fragment = fragment
        last = rows[-1]
        best.points += rows.shape[0]
        best.end_m = float(position[last])
        best.end_scan = int(scan[last])
        best.end_x = float(x[last])
        best.end_z = float(z[last])
        # the slope over the fragment's last half metre, for bridging the next gap
        tail = rows[position[rows] >= best.end_m - 0.5]
        if tail.shape[0] >= MIN_TRACK_POINTS and np.ptp(position[tail]) > 0.1:
            p = position[tail] - position[tail].mean()
            spread = float(p @ p)
            best.slope_x = float(p @ x[tail]) / spread
            best.slope_z = float(p @ z[tail]) / spread
        return best

    def _detach(self, track: _Track, track_of_fragment: IntArray) -> None:
        """Set a track's last fragment apart as a new track; restore the track's end."""
        assert track.before is not None
        apart = _Track(
            self._next_track,
            np.nan,
            track.last_start_scan,
            track.end_m,
            track.end_scan,
            track.end_x,
            track.end_z,
            points=track.last_points,
        )
        self._next_track += 1
        if track.last_fragment >= 0:  # in the block being added
            track_of_fragment[track.last_fragment] = apart.id
            apart.start_m = track.before[0]  # approximately: it started after the track's end
        else:  # held in the store from an earlier block
            rows = (self._store.track == track.id) & (self._store.scan >= track.last_start_scan)
            self._store.track[rows] = apart.id
            apart.start_m = float(self._store.position_m[rows].min())
        self._open[apart.id] = apart
        track.restore(track.before)
        track.before = None

    def _end(self, track: _Track) -> None:
        """A track that can no longer grow: unconfirmed ones are dropped with their points."""
        del self._open[track.id]
        if track.confirmed:
            self._closed[track.id] = track
            if track.wire >= 0:
                self._lost.append(track)

    def _close_stale(self) -> None:
        config = self.config
        for track in list(self._open.values()):
            if self._last_m - track.end_m > config.max_gap_m:
                self._end(track)
        horizon = self._last_m - config.reidentify_m - config.max_gap_m
        self._lost = [t for t in self._lost if t.end_m >= horizon]

    def _number(self, track: _Track, scan: int, position: float, x: float, z: float) -> int:
        """Wire number of a track's first contact point: an ended wire's, or a new one.

        A numbered track that ended before this point (lost, or open but unable to grow any
        more), within ``reidentify_m`` and near where it ended, hands its number over; an
        open one is then ended, so that one number never runs twice at once.
        """
        config = self.config
        taken = {t.wire for t in self._open.values() if t.wire >= 0 and t.end_scan >= scan}
        # open tracks that can no longer grow: no fragment after this scan starts within the
        # gap a track bridges
        ended = [
            t
            for t in self._open.values()
            if t.wire >= 0 and t.end_scan < scan and position - t.end_m > config.max_gap_m
        ]
        best: _Track | None = None
        best_distance = np.inf
        for old in [*self._lost, *ended]:
            gap = position - old.end_m
            if old is track or old.wire in taken or gap > config.reidentify_m:
                continue
            grown = config.gap_gate_mm_per_m * min(max(gap, 0.0), REIDENTIFY_GROWTH_M)
            gate = config.reidentify_mm + grown
            distance = max(abs(old.end_x - x), abs(old.end_z - z))
            if distance <= gate and distance / gate < best_distance:
                best, best_distance = old, distance / gate
        if best is None:
            number = self._next_wire
            self._next_wire += 1
            return number
        if best in self._lost:
            self._lost.remove(best)
        else:
            self._end(best)
            self._lost.remove(best)
        return best.wire

    def _release(self, *, final: bool) -> TrackedPoints:
        """Return the points no undecided track can still change (steps 4-6)."""
        store = self._store
        horizon_scan = np.iinfo(np.int64).max if final else self._last_scan + 1
        undecided = [t.id for t in self._open.values() if not t.confirmed]
        starts = store.scan[np.isin(store.track, undecided)]
        if starts.shape[0] and not final:
            horizon_scan = min(horizon_scan, int(starts.min()))
        if not final:
            # a gap that may still be bridged must be seen to its end: what follows a scan
            # by up to max_gap_m is known before it is released (so the result does not
            # depend on how the run is cut into blocks)
            recent = store.position_m > self._last_m - self.config.max_gap_m
            if np.any(recent):
                horizon_scan = min(horizon_scan, int(store.scan[recent].min()))
        released = store.split(store.scan < horizon_scan)
        tracks = {**self._closed, **{t.id: t for t in self._open.values() if t.confirmed}}
        wire_track = np.isin(released.track, list(tracks))
        above, company, crossing = self._above_a_wire(released, tracks)
        contact = wire_track & ~above & (released.z_mm <= self.config.max_height_mm)
        above_lost = contact & self._above_a_lost_wire(released, tracks)
        lower_beneath = self._lower_wire_beneath(released, contact, tracks)
        above_before = self._above_before(released, wire_track, above | above_lost, company)
        # numbers, for tracks whose first contact point this is (in order of appearance)
        wire = np.full(released.scan.shape[0], -1, dtype=np.int64)
        rows = np.flatnonzero(contact)
        ids, first = np.unique(released.track[rows], return_index=True)
        for track_id, row in sorted(
            zip(ids.tolist(), rows[first].tolist(), strict=True), key=lambda item: item[1]
        ):
            track = tracks[track_id]
            if track.wire < 0:
                track.wire = self._number(
                    track,
                    int(released.scan[row]),
                    float(released.position_m[row]),
                    float(released.x_mm[row]),
                    float(released.z_mm[row]),
                )
                if track.id not in self._open:  # it ended before its first point was out
                    self._lost.append(track)
            wire[released.track == track_id] = track.wire
        faced = released.face_mm > 0.0  # NaN: faces seen, not agreed on
        one_wire = self._on_its_line(released, wire, contact & crossing & faced, tracks)
        uncertain = contact & ((crossing & ~one_wire) | lower_beneath | above_before) | above_lost
        keep = contact & (wire >= 0)
        keep &= self._on_track(released)
        keep &= self._consistent(released, wire, keep, tracks)
        self._remember(released, tracks)
        return TrackedPoints(
            scan=released.scan[keep],
            wire=wire[keep],
            position_m=released.position_m[keep],
            x_mm=released.x_mm[keep],
            z_mm=released.z_mm[keep],
            face_mm=np.where(crossing, np.nan, released.face_mm)[keep],
            columns={
                **{k: v[keep] for k, v in released.columns.items()},
                UNCERTAIN_COLUMN: uncertain[keep],
            },
        )

    def _lower_wire_beneath(
        self, released: _Store, candidate: NDArray[np.bool_], tracks: Mapping[int, _Track]
    ) -> NDArray[np.bool_]:
        """Whether a lower wire shows beneath each ``candidate`` released point (step 4).

        Counts, within ``max_gap_m`` along the track (released before, now, or held ahead),
        the verified points of no confirmed track (those are ``_above_a_wire``'s) that lie
        more than ``messenger_gap_mm`` below the point's own track, its height interpolated
        at theirs: ``LOWER_WIRE_POINTS`` of them are a lower wire. Two-view points do not
        count: two cameras that see two wires close together make chains of ghosts beneath
        them. Remembers the verified points released now for the next call.
        """
        store, reach = self._store, self.config.max_gap_m
        parts = (self._behind, released.take(released.verified), store.take(store.verified))
        position = np.concatenate([part.position_m for part in parts])
        order = np.argsort(position, kind="stable")
        position = position[order]
        height = np.concatenate([part.z_mm for part in parts])[order]
        track = np.concatenate([part.track for part in parts])[order]
        ahead = np.repeat([False, False, True], [part.scan.shape[0] for part in parts])[order]
        unconfirmed = ~np.isin(track, list(tracks))
        beneath = np.zeros(released.scan.shape[0], dtype=bool)
        for track_id in np.unique(released.track[candidate]).tolist():  # one step per wire
            mine = candidate & (released.track == track_id)
            _, own_m, _, own_z = self._track_points(
                released, released.track == track_id, store.track == track_id, None
            )
            own_height = np.interp(position, own_m, own_z)  # in scan order
            lower = unconfirmed & (height < own_height - self.config.messenger_gap_mm)
            first = np.searchsorted(position, released.position_m[mine] - reach, side="left")
            last = np.searchsorted(position, released.position_m[mine] + reach, side="right")
            beneath[mine] = _window_count(lower, first, last) >= LOWER_WIRE_POINTS
        if released.scan.shape[0]:
            done = ~ahead & (position >= released.position_m[-1] - reach)
            self._behind = _Store(
                np.zeros(int(done.sum()), np.int64),
                position[done],
                np.zeros(int(done.sum())),
                height[done],
                track[done],
                np.ones(int(done.sum()), bool),
                np.zeros(int(done.sum())),
                {},
            )
        return beneath

    def _above_a_wire(
        self, released: _Store, tracks: Mapping[int, _Track]
    ) -> tuple[NDArray[np.bool_], IntArray, NDArray[np.bool_]]:
        """Whether each released point lies above a confirmed track at its scan, how many
        confirmed tracks are in view there (its own included), and whether another track
        crosses it there. Above is more than ``messenger_gap_mm`` above the lowest (a
        messenger, a wire raised out of running), or more than ``RESTING_MM`` above one within
        ``RESTING_ACROSS_MM`` across (a crossing's pipe resting on the wire, a wire riding
        over it: the pantograph touches the lower). Crossing is another wire's track (one
        seen in a scan with it) within ``CROSSING_MM`` across and ``RESTING_MM`` in height:
        one image of both wires.

        Each track is interpolated between its points (so a scan where it was missed still
        counts) and, for the lowest, held beyond its ends for ``max_gap_m`` (a wire missed in
        the first or last scans it is seen in); resting and crossing are judged within its
        span.
        """
        lowest = np.full(released.scan.shape[0], np.inf)
        resting = np.zeros(released.scan.shape[0], dtype=bool)
        crossing = np.zeros(released.scan.shape[0], dtype=bool)
        company = np.zeros(released.scan.shape[0], dtype=np.int64)
        store = self._store
        reach = self.config.max_gap_m
        points = {
            track_id: self._track_points(
                released,
                released.track == track_id,
                store.track == track_id,
                self._last_released.get(track_id),
            )
            for track_id in tracks
        }
        for track_id, (s, p, x, h) in points.items():  # one step per wire in view
            if s.shape[0] == 0:
                continue
            near = (released.position_m >= p[0] - reach) & (released.position_m <= p[-1] + reach)
            z = np.where(near, np.interp(released.scan, s, h), np.inf)
            lowest = np.minimum(lowest, z)
            company += near
            across = np.abs(np.interp(released.scan, s, x) - released.x_mm)
            # resting and crossing within the track's own span: held beyond its ends, its x
            # would cross others, and its last height would lie beneath the wire's own next
            # track (a track that ended on a stray point 33 mm low took a metre of the wire
            # that continued it for resting on it: sweep scene 43)
            spanned = (released.scan >= s[0]) & (released.scan <= s[-1])
            resting |= spanned & (across <= RESTING_ACROSS_MM) & (released.z_mm > z + RESTING_MM)
            # crossing: by a track seen in a scan with it (another wire: one wire's two tracks,
            # by its face and by its silhouettes, never share a scan)
            level = spanned & (np.abs(released.z_mm - z) <= RESTING_MM)
            others = [
                other
                for other, (s_other, *_) in points.items()
                if other != track_id and np.isin(s_other, s).any()
            ]
            crossing |= np.isin(released.track, others) & (across <= CROSSING_MM) & level
        above = resting | (released.z_mm > lowest + self.config.messenger_gap_mm)
        return above, company, crossing

    def _above_a_lost_wire(
        self, released: _Store, tracks: Mapping[int, _Track]
    ) -> NDArray[np.bool_]:
        """Whether each released point lies above where a numbered wire that ended before it
        can run now (step 4): more than ``messenger_gap_mm`` plus ``CONTACT_GRADIENT_MM_PER_M``
        of the distance since its end above its last point, as far along as that wire was
        seen (``reidentify_m`` at most). A contact wire does not climb to its messenger's
        height: such a point is a messenger whose contact wire the cameras lost, or a wire
        out of running. The lost wire must have been seen over as long a stretch as the
        point's track: a short run of ghosts beneath a wire is no evidence against it."""
        config = self.config
        span = np.full(released.scan.shape[0], np.inf)
        for track_id, track in tracks.items():  # one step per wire in view
            span[released.track == track_id] = track.span_m
        result = np.zeros(released.scan.shape[0], dtype=bool)
        for lost in self._lost:  # one step per lost wire
            after = released.position_m - lost.end_m
            remembered = min(lost.span_m, config.reidentify_m)
            near = (span <= lost.span_m) & (after > 0.0) & (after <= remembered)
            rise = config.messenger_gap_mm + CONTACT_GRADIENT_MM_PER_M * after
            result |= near & (released.track != lost.id) & (released.z_mm > lost.end_z + rise)
        return result

    def _above_before(
        self,
        released: _Store,
        wire_track: NDArray[np.bool_],
        above: NDArray[np.bool_],
        company: IntArray,
    ) -> NDArray[np.bool_]:
        """Whether each released point of a confirmed track is alone in view on a track that
        was last seen above another wire (step 4): a messenger whose contact wire the cameras
        lost. A track that came level with another wire since (an overlap's wire come down
        into running) is not. Remembers each track's last state for the next call."""
        state = np.where(above, 1, np.where(company > 1, -1, 0))
        result = np.zeros(released.scan.shape[0], dtype=bool)
        for track_id in np.unique(released.track[wire_track]).tolist():  # one step per wire
            mine = np.flatnonzero(released.track == track_id)
            states = np.concatenate([[self._above.get(track_id, 0)], state[mine]])
            said = np.maximum.accumulate(np.where(states != 0, np.arange(states.shape[0]), 0))
            last = states[said]  # the last state that was not "alone", carried forward
            result[mine] = (state[mine] == 0) & (last[1:] == 1)
            self._above[track_id] = int(last[-1])
        return result

    def _track_points(
        self,
        released: _Store,
        mine: NDArray[np.bool_],
        ahead: NDArray[np.bool_],
        last: tuple[int, float, float, float] | None,
    ) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
        """Scan, position, x and z of a track's points ``(k,)`` each, in scan order: ``last``
        (remembered from an earlier release, or None), the released rows ``mine`` and the
        held rows ``ahead``."""
        store = self._store
        parts = [
            (
                released.scan[mine],
                released.position_m[mine],
                released.x_mm[mine],
                released.z_mm[mine],
            ),
            (store.scan[ahead], store.position_m[ahead], store.x_mm[ahead], store.z_mm[ahead]),
        ]
        if last is not None:
            ls, lp, lx, lz = (np.array([v]) for v in last)
            parts.insert(0, (ls, lp, lx, lz))
        s, p, x, z = (np.concatenate([part[i] for part in parts]) for i in range(4))
        return s.astype(np.int64), p, x, z

    def _on_track(self, released: _Store) -> NDArray[np.bool_]:
        """Whether each released point is verified, or lies where its track's verified points
        put it (interpolated between them, extrapolated beyond) within the tight link gate and
        ``UNVERIFIED_REACH_M`` of one of them.

        A chain of unverified points joins a track through its first point only; each of its
        points is checked here, when the verified points on both sides of it are known.
        """
        config = self.config
        ok = released.verified.copy()
        store = self._store
        for track_id in np.unique(released.track[~ok]).tolist():  # one step per track
            mine = released.track == track_id
            s, p, x, z = self._track_points(
                released,
                mine & released.verified,
                (store.track == track_id) & store.verified,
                self._last_verified.get(track_id),
            )
            rows = np.flatnonzero(mine & ~released.verified)
            if s.shape[0] == 0:
                continue
            order = np.argsort(s, kind="stable")
            s, p, x, z = s[order], p[order], x[order], z[order]
            q = released.scan[rows]
            after = np.searchsorted(s, q)  # first verified point after (scans differ)
            before_m = p[np.maximum(after - 1, 0)]
            after_m = p[np.minimum(after, s.shape[0] - 1)]
            here = released.position_m[rows]
            between = (after > 0) & (after < s.shape[0])
            gap = np.where(
                between,
                np.minimum(here - before_m, after_m - here),
                np.where(after > 0, here - before_m, after_m - here),
            )
            # between verified points the wire is interpolated (a kink bends it by a little
            # over the gap); beyond them it is extrapolated (its slope at most)
            growth = np.where(between, 0.1, 1.0) * np.abs(gap)
            ok[rows] = (
                (np.abs(gap) <= UNVERIFIED_REACH_M)
                & (
                    np.abs(released.x_mm[rows] - np.interp(q, s, x))
                    <= config.link_mm + config.x_mm_per_m * growth
                )
                & (
                    np.abs(released.z_mm[rows] - np.interp(q, s, z))
                    <= config.link_mm + config.z_mm_per_m * growth
                )
            )
        return ok

    def _consistent(
        self,
        released: _Store,
        wire: IntArray,
        candidate: NDArray[np.bool_],
        tracks: Mapping[int, _Track],
    ) -> NDArray[np.bool_]:
        """Whether each ``candidate`` released point lies where its wire's neighbours put it
        (others: true). The wire is continuous: a point is checked against the medians of
        its wire's ``NEIGHBOURS`` points on either side within ``NEIGHBOUR_M`` (interpolated
        between the two medians' positions), within ``link_mm`` plus three robust
        deviations of the neighbours about their medians, in ``x`` and in ``z``. A fitting's
        points that scatter off the wire for a few scans (a clamp, a dropper's foot) fail,
        also where they broke the wire's track in two (checked by wire number, not by
        track); a wire's own scatter, however wide, does not. A point with fewer than two
        neighbours on a side (a wire's end, a sparse stretch) is not checked. Every point of
        the wire's tracks is a neighbour, so that the result does not depend on where the
        run is cut; remembers each wire's last points for the next call."""
        ok = np.ones(released.scan.shape[0], dtype=bool)
        for number in np.unique(wire[candidate]).tolist():  # one step per wire
            mine, (p, x, z, _), rows = self._wire_points(released, wire, number, tracks)
            behind = self._recent.get(number, (np.zeros(0),) * len(_NEIGHBOUR_VALUES))
            sides = [_side(p, rows, sign) for sign in (-1, 1)]
            check = candidate[mine] & np.all([near.sum(axis=1) >= 2 for _, near in sides], 0)
            if check.any():
                at = rows[check]
                before, after = (
                    _side_medians(index[check], near[check], p, x, z) for index, near in sides
                )
                span = np.where(after[0] > before[0], after[0] - before[0], 1.0)
                t = np.clip((p[at] - before[0]) / span, 0.0, 1.0)
                off = np.zeros(at.shape[0], dtype=bool)
                for k, v in ((1, x), (2, z)):
                    spread = before[k + 2] + after[k + 2]
                    tolerance = self.config.link_mm + 3.0 * 1.4826 * spread
                    expected = before[k] + t * (after[k] - before[k])
                    off |= np.abs(v[at] - expected) > tolerance
                ok[mine[check]] = ~off
            self._recent[number] = tuple(
                np.concatenate([old, getattr(released, n)[mine]])[-NEIGHBOURS:]
                for old, n in zip(behind, _NEIGHBOUR_VALUES, strict=True)
            )
        if released.scan.shape[0]:  # forget wires no later point can have as neighbours
            edge = float(released.position_m[-1]) - NEIGHBOUR_M
            for number in [w for w, (p, *_) in self._recent.items() if p[-1] < edge]:
                del self._recent[number]
        return ok

    def _wire_points(
        self, released: _Store, wire: IntArray, number: int, tracks: Mapping[int, _Track]
    ) -> tuple[IntArray, tuple[FloatArray, ...], IntArray]:
        """Wire ``number``'s points about the released ones, in order along the track: the
        last ``NEIGHBOURS`` released before (remembered), the released ones (``mine``, rows
        of ``released``) and the first ``NEIGHBOURS`` held ahead. Returns ``mine``, their
        ``_NEIGHBOUR_VALUES`` (position [m], ``x``, ``z`` and face width [mm]), and where
        ``mine`` lie in those."""
        mine = np.flatnonzero(wire == number)
        own = [t for t, track in tracks.items() if track.wire == number]
        ahead = np.flatnonzero(np.isin(self._store.track, own))[:NEIGHBOURS]
        behind = self._recent.get(number, (np.zeros(0),) * len(_NEIGHBOUR_VALUES))
        values = tuple(
            np.concatenate([old, getattr(released, n)[mine], getattr(self._store, n)[ahead]])
            for old, n in zip(behind, _NEIGHBOUR_VALUES, strict=True)
        )
        return mine, values, behind[0].shape[0] + np.arange(mine.shape[0])

    def _on_its_line(
        self,
        released: _Store,
        wire: IntArray,
        candidate: NDArray[np.bool_],
        tracks: Mapping[int, _Track],
    ) -> NDArray[np.bool_]:
        """Whether each ``candidate`` released point lies on its wire's line (others: false;
        :func:`_on_a_side_s_line`), the line of its wire's points on one side of it or the
        other: where a track goes on along the other wire past a crossing, the points of each
        wire have their own wire's points on one side, and an image of both wires, between
        them, lies on neither side's line."""
        ok = np.zeros(released.scan.shape[0], dtype=bool)
        for number in np.unique(wire[candidate]).tolist():  # one step per wire
            mine, (p, x, z, face), rows = self._wire_points(released, wire, number, tracks)
            check = candidate[mine]
            ok[mine[check]] = _on_a_side_s_line(p, x, z, face, rows[check])
        return ok

    def _remember(self, released: _Store, tracks: Mapping[int, _Track]) -> None:
        """Keep each track's last released point; forget tracks that hold nothing more and
        ended more than ``max_gap_m`` before the last point released."""
        if released.scan.shape[0]:
            ids, from_end = np.unique(released.track[::-1], return_index=True)
            last = released.scan.shape[0] - 1 - from_end  # last row of each track
            for track_id, row in zip(ids.tolist(), last.tolist(), strict=True):
                if track_id in tracks:
                    self._last_released[track_id] = (
                        int(released.scan[row]),
                        float(released.position_m[row]),
                        float(released.x_mm[row]),
                        float(released.z_mm[row]),
                    )
            sure = released.verified
            ids, from_end = np.unique(released.track[sure][::-1], return_index=True)
            last = np.flatnonzero(sure)[sure.sum() - 1 - from_end]
            for track_id, row in zip(ids.tolist(), last.tolist(), strict=True):
                if track_id in tracks:
                    self._last_verified[track_id] = (
                        int(released.scan[row]),
                        float(released.position_m[row]),
                        float(released.x_mm[row]),
                        float(released.z_mm[row]),
                    )
        # a closed track's height still counts up to max_gap_m beyond its end (_above_a_wire)
        held = set(np.unique(self._store.track).tolist())
        if released.scan.shape[0]:
            self._released_m = float(released.position_m[-1])
        reach = self.config.max_gap_m
        for track_id, track in list(self._closed.items()):
            if track_id not in held and track.end_m + reach < self._released_m:
                del self._closed[track_id]
        alive = set(self._open) | set(self._closed)
        for book in (self._last_released, self._last_verified, self._above):
            for track_id in [t for t in book if t not in alive]:
                del book[track_id]


_NEIGHBOUR_VALUES = ("position_m", "x_mm", "z_mm", "face_mm")
"""What a point is checked against of its wire's neighbours (``WireTracker._wire_points``)."""


def _side(p: FloatArray, rows: IntArray, sign: int) -> tuple[IntArray, NDArray[np.bool_]]:
    """Each row's ``NEIGHBOURS`` neighbours on one side (``sign``: -1 before, 1 after):
    their indices into ``p`` (positions in order, clipped to it) ``(m, NEIGHBOURS)``, and
    which of them exist and lie within ``NEIGHBOUR_M`` of the row along the track."""
    wanted = rows[:, None] + sign * np.arange(1, NEIGHBOURS + 1)
    index = np.clip(wanted, 0, p.shape[0] - 1)
    near = (wanted == index) & (np.abs(p[index] - p[rows][:, None]) <= NEIGHBOUR_M)
    return index, near


def _on_a_side_s_line(
    p: FloatArray, x: FloatArray, z: FloatArray, face: FloatArray, at: IntArray
) -> NDArray[np.bool_]:
    """Whether the points ``at`` (indices into the wire's points ``p`` [m], ``x``, ``z`` and
    face widths ``face`` [mm], in order along the track) lie on the straight line, in ``x``
    and in ``z``, that the ``NEIGHBOURS`` points within ``NEIGHBOUR_M`` on one side of them
    give: three of them at least, each within half ``CROSSING_LINE_MM`` of the line fitted
    to them by least squares (one wire's points) and with a face as wide as the point's
    within ``CROSSING_WIDTH_MM`` (one wire's face), the point within ``CROSSING_LINE_MM`` of
    the line."""
    fits = np.zeros(at.shape[0], dtype=bool)
    for sign in (-1, 1):
        index, near = _side(p, at, sign)
        weight = near.astype(np.float64)
        count = weight.sum(axis=1)
        with np.errstate(invalid="ignore"):
            alike = np.abs(face[index] - face[at][:, None]) <= CROSSING_WIDTH_MM
        side = (count >= 3) & np.all(alike | ~near, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            p_mean = (weight * p[index]).sum(axis=1) / count
        dp = np.where(near, p[index] - p_mean[:, None], 0.0)
        for v in (x, z):
            with np.errstate(invalid="ignore", divide="ignore"):
                v_mean = (weight * v[index]).sum(axis=1) / count
                slope = (dp * (v[index] - v_mean[:, None])).sum(axis=1) / (dp * dp).sum(axis=1)
            line = v_mean[:, None] + slope[:, None] * dp  # at the neighbours
            scatter = np.where(near, np.abs(v[index] - line), 0.0).max(axis=1)
            off = np.abs(v_mean + slope * (p[at] - p_mean) - v[at])
            side &= (scatter <= 0.5 * CROSSING_LINE_MM) & (off <= CROSSING_LINE_MM)
        fits |= side
    return fits


def _side_medians(
    index: IntArray, near: NDArray[np.bool_], p: FloatArray, x: FloatArray, z: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Median position, ``x`` and ``z`` of each row's neighbours on one side (``index``,
    ``near``: :func:`_side`), and the median absolute deviation of their ``x`` and of their
    ``z`` about their medians (half of it each: the two sides' halves add up to about the
    pooled deviation)."""
    values = [np.where(near, v[index], np.nan) for v in (p, x, z)]
    medians = [row_median(v) for v in values]
    deviations = [
        0.5 * row_median(np.abs(v - m[:, None]))
        for v, m in zip(values[1:], medians[1:], strict=True)
    ]
    return medians[0], medians[1], medians[2], deviations[0], deviations[1]


def _window_count(rows: NDArray[np.bool_], first: IntArray, last: IntArray) -> IntArray:
    """How many of ``rows`` lie in each window ``first[i]:last[i]`` (cumulative sums)."""
    total = np.concatenate([[0], np.cumsum(rows, dtype=np.int64)])
    return np.asarray(total[last] - total[first], dtype=np.int64)
