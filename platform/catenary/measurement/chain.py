"""The measurement chain after the processor: roof frame to track frame to worn face width.

A processor turns blocks of scans into :class:`~catenary.domain.WireObservations` in the roof
frame, releasing each scan's rows when its wire tracking has decided them (possibly blocks
later). :class:`MeasurementChain` takes the blocks and those observations, in run order, and
gives :class:`TrackSamples`:

1. **vehicle compensation** (``catenary.measurement.vehicle.roof_to_track``): each row is carried to
   the track frame with the displacement sensors of its own scan, kept for ``history_m`` of track
   behind the latest block (a processor must release a scan before the train is that far on);
   a row whose scan had a faulty or missing sensor sample is flagged ``vehicle_fault``;
2. **stagger-angle correction** (``catenary.measurement.wear``): ``w0 = w cos θ`` with ``θ`` from
   the measured stagger gradient of the row's own wire, fitted with ``window_m`` of the wire's
   samples on either side: a wire's rows are held until it has been seen ``window_m``
   further (or until the train is ``history_m + window_m`` past its last row: it has ended),
   and the last ``window_m`` of rows already given out are kept as the left context;
3. **screen** (``catenary.measurement.wear.screened_wear_width_mm``): a width that departs from the
   widths of its wire on either side for a few scans (a fitting's disturbance) is left out
   (NaN); the row stays. Rows are held ``SCREEN_NOISE_HALF_WINDOW_M`` longer (how far the
   screen looks), so that it sees the stagger-corrected widths of both sides.

Rows the processor flags ``selection_uncertain`` (perhaps a messenger, a dropper or an arm,
not the contact wire) are carried through with their flag, but steps 2 and 3 take them apart
from the wire's other rows: their stagger never enters the wire's angle fit, nor their width
its screen, and theirs come from the uncertain rows of the same wire number only.

Memory is bounded by ``history_m`` of scans and ``2 window_m`` (and the screen's reach) of
rows per wire, whatever the run's length. Residual thickness and chainage come later, once
the run's chainage is aligned (they need the mast register's wire types and the whole run's
registration points).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from catenary.arrays import BoolArray, FloatArray, IndexArray, IntArray
from catenary.domain import ScanBlock, VehicleGeometry, WireObservations
from catenary.measurement.vehicle import roof_to_track
from catenary.measurement.wear import (
    DEFAULT_WINDOW_M,
    SCREEN_NOISE_HALF_WINDOW_M,
    corrected_wear_width_mm,
    screened_wear_width_mm,
    stagger_angle_rad,
)

__all__ = ["VEHICLE_HISTORY_M", "MeasurementChain", "TrackSamples"]

VEHICLE_HISTORY_M = 200.0
"""Track behind the latest block whose scans' sensor values are kept [m]: far more than any
processor holds rows back (the line-scan tracker decides a wire within a few metres)."""


@dataclass(frozen=True)
class TrackSamples:
    """Rows of contact wire samples in the track frame, each ``(m,)``.

    ``wear_width_mm`` is across the wire (stagger-angle corrected); NaN where the cameras
    did not agree on the face, the angle could not be fitted or the screen left it out, 0.0
    where no face was seen (and its neighbours saw none either). ``selection_uncertain``: the
    processor could not decide that the row is the contact wire. ``x_roof_mm``, ``z_roof_mm``
    are the processor's point in the roof frame, before compensation (where the cameras saw
    it: image evidence is cut there).
    """

    scan: IntArray
    position_m: FloatArray
    wire: IntArray
    height_mm: FloatArray
    stagger_mm: FloatArray
    wear_width_mm: FloatArray
    cameras: IntArray
    vehicle_fault: BoolArray
    selection_uncertain: BoolArray
    x_roof_mm: FloatArray
    z_roof_mm: FloatArray

    @property
    def rows(self) -> int:
        return int(self.scan.shape[0])

    @classmethod
    def empty(cls) -> TrackSamples:
        return cls(**{f.name: np.zeros(0, _DTYPES[f.name]) for f in fields(cls)})

    @classmethod
    def concatenate(cls, parts: list[TrackSamples]) -> TrackSamples:
        if not parts:
            return cls.empty()
        return cls(
            **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)}
        )

    def take(self, index: IndexArray | BoolArray) -> TrackSamples:
        return TrackSamples(**{f.name: getattr(self, f.name)[index] for f in fields(self)})


_DTYPES = {
    "scan": np.int64,
    "position_m": np.float64,
    "wire": np.int64,
    "height_mm": np.float64,
    "stagger_mm": np.float64,
    "wear_width_mm": np.float64,
    "cameras": np.int64,
    "vehicle_fault": np.bool_,
    "selection_uncertain": np.bool_,
    "x_roof_mm": np.float64,
    "z_roof_mm": np.float64,
}

_Stream = tuple[int, bool]
"""Rows processed along the track together: a wire number, and whether the selection was
uncertain."""


class MeasurementChain:
    """Vehicle compensation, stagger-angle correction and the along-track screen of a
    processor's observations.

    Parameters
    ----------
    geometry : VehicleGeometry
        The car body's geometry (the rig calibration's vehicle).
    window_m : float
        Length of track of the stagger-gradient fit [m] (``catenary.measurement.wear``).
    history_m : float
        Track behind the latest block whose scans' sensors are kept [m].

    Notes
    -----
    Call :meth:`push` once per block, in run order, with the observations the processor
    returned for it; then :meth:`finish` with the processor's final observations. Each call
    returns the rows now complete, sorted by scan and wire.
    """

    def __init__(
        self,
        geometry: VehicleGeometry,
        *,
        window_m: float = DEFAULT_WINDOW_M,
        history_m: float = VEHICLE_HISTORY_M,
    ) -> None:
        self.geometry = geometry
        self.window_m = window_m
        self.history_m = history_m
        self._first_scan = 0  # run index of the first scan kept
        self._next_scan = 0
        self._latest_position_m = -np.inf
        self._position = np.zeros(0)
        self._sensors = np.zeros((3, 0))  # left, right, lateral [mm]
        self._fault = np.zeros(0, dtype=bool)
        self._pending: dict[_Stream, TrackSamples] = {}  # per stream: rows not given out yet
        self._context: dict[_Stream, TrackSamples] = {}  # per stream: the last rows given out

    def push(self, block: ScanBlock, observations: WireObservations) -> TrackSamples:
        """Add one block's scans and the observations released with it."""
        if block.first_scan != self._next_scan:
            raise ValueError(f"block at scan {block.first_scan}, expected {self._next_scan}")
        vehicle = block.vehicle
        n = block.scans
        sensors = np.stack([vehicle.left_mm, vehicle.right_mm, vehicle.lateral_mm])
        if sensors.shape != (3, n):
            raise ValueError(f"block at scan {block.first_scan}: vehicle samples are not [{n}]")
        fault = vehicle.fault if vehicle.fault.shape == (n,) else np.zeros(n, dtype=bool)
        self._position = np.concatenate([self._position, block.position_m])
        self._sensors = np.concatenate([self._sensors, sensors], axis=1)
        self._fault = np.concatenate([self._fault, fault | ~np.isfinite(sensors).all(axis=0)])
        self._next_scan += n
        if n:
            self._latest_position_m = float(block.position_m[-1])
        self._add(observations)
        if n:
            keep = np.searchsorted(self._position, block.position_m[-1] - self.history_m)
            self._first_scan += int(keep)
            self._position = self._position[keep:]
            self._sensors = self._sensors[:, keep:]
            self._fault = self._fault[keep:]
        return self._release(final=False)

    def finish(self, observations: WireObservations) -> TrackSamples:
        """Add the processor's last observations and give out every row still held."""
        self._add(observations)
        return self._release(final=True)

    def _add(self, observations: WireObservations) -> None:
        if observations.rows == 0:
            return
        index = observations.scan - self._first_scan
        if index.min() < 0 or observations.scan.max() >= self._next_scan:
            raise ValueError(
                f"observation of scan {int(observations.scan.min())} outside the scans kept "
                f"({self._first_scan}-{self._next_scan - 1}): a processor must release a scan "
                f"within {self.history_m:g} m"
            )
        left, right, lateral = self._sensors[:, index]
        stagger, height = roof_to_track(
            observations.x_roof_mm, observations.z_roof_mm, left, right, lateral, self.geometry
        )
        rows = TrackSamples(
            scan=observations.scan.astype(np.int64),
            position_m=self._position[index],
            wire=observations.wire.astype(np.int64),
            height_mm=height,
            stagger_mm=stagger,
            wear_width_mm=np.asarray(observations.wear_width_mm, dtype=np.float64),
            cameras=observations.cameras.astype(np.int64),
            vehicle_fault=self._fault[index],
            selection_uncertain=observations.selection_uncertain,
            x_roof_mm=np.asarray(observations.x_roof_mm, dtype=np.float64),
            z_roof_mm=np.asarray(observations.z_roof_mm, dtype=np.float64),
        )
        for uncertain in (False, True):
            flagged = rows.take(rows.selection_uncertain == uncertain)
            for wire in np.unique(flagged.wire):  # a loop per wire, not per row
                mine = flagged.take(flagged.wire == wire)
                stream = (int(wire), uncertain)
                held = self._pending.get(stream)
                self._pending[stream] = mine if held is None else held.concatenate([held, mine])

    def _release(self, *, final: bool) -> TrackSamples:
        out = []
        for stream in list(self._pending):
            pending = self._pending[stream]
            if pending.rows == 0:
                continue
            frontier = float(np.max(pending.position_m))
            # a wire seen last further back than any row can still come: nothing will follow
            idle = frontier < self._latest_position_m - self.history_m - self.window_m
            ready = (
                np.ones(pending.rows, dtype=bool)
                if final or idle
                else pending.position_m <= frontier - self.window_m - SCREEN_NOISE_HALF_WINDOW_M
            )
            if not ready.any():
                continue
            context = self._context.get(stream, TrackSamples.empty())
            both = TrackSamples.concatenate([context, pending])
            theta = stagger_angle_rad(both.position_m, both.stagger_mm, self.window_m)
            # the context's widths are corrected already (and kept unscreened)
            corrected = np.concatenate(
                [
                    context.wear_width_mm,
                    corrected_wear_width_mm(pending.wear_width_mm, theta[context.rows :]),
                ]
            )
            screened = screened_wear_width_mm(both.position_m, corrected)
            done = replace(pending.take(ready), wear_width_mm=corrected[context.rows :][ready])
            out.append(replace(done, wear_width_mm=screened[context.rows :][ready]))
            self._pending[stream] = pending.take(~ready)
            given = TrackSamples.concatenate([context, done])
            last = float(np.max(done.position_m))
            # as far back as the angle's window and the screen's noise differences reach
            reach = max(self.window_m, 2.0 * SCREEN_NOISE_HALF_WINDOW_M)
            self._context[stream] = given.take(given.position_m >= last - reach)
        released = TrackSamples.concatenate(out)
        order = np.lexsort((released.wire, released.scan))
        return released.take(order)
