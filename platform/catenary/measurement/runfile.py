"""The recorded run file: FORMATS.md "Recorded run: HDF5", written and read in blocks of scans.

Writing
-------
:class:`RunFileWriter` is the one writer every recording source uses (simulator, CAN sensors,
cameras). It creates the FORMATS.md layout with every dataset resizable and chunked along
scans, validates what it is given before writing any of it, and streams: small appends are
staged in memory up to about one chunk, larger ones go straight to the file, so memory does
not grow with the run's length.

Choices of this project (FORMATS.md leaves them open):

* **Chunks.** Each camera's ``lines`` are chunked ``[rows, W]`` with ``rows`` the power of two
  that makes a chunk 1-2 MiB (``chunk_rows_for``); ``/scans/*`` and ``/vehicle/*`` are chunked
  by :data:`SERIES_CHUNK` samples (512 KiB).
* **Compression.** The default is :data:`DEFAULT_COMPRESSION` = ``None`` (chunked,
  uncompressed). No standard HDF5 filter decompresses camera lines fast enough to stream a
  run at the target 100,000 scans/s on one core. Measured with ``benchmarks/read_runfile.py
  --compare`` (four 4096-pixel uint8 cameras, sky with 2 DN noise and wire peaks): none
  160,000-230,000 scans/s; lzf 14,000 (1.2x smaller file); gzip levels 1/4/6 13,000-16,000
  (1.7x smaller), and gzip writes only 1,500-3,800 scans/s.
  ``compression="gzip"`` uses level :data:`DEFAULT_GZIP_LEVEL` (1: higher levels gain under
  1 % on camera lines at 2-3x the write time) with the shuffle filter; ``"lzf"`` and
  ``"szip"`` are accepted too, for archiving. The same filters apply to every dataset.
* **Durability.** On the first append ``flush_interval_s`` after the last flush, staged
  scans are written and the file is flushed, so a power cut loses about that much recording
  (provided HDF5 can still open the file: without SWMR it may refuse a file cut mid-write).
* **Optional datasets** (FORMATS.md). ``/cameras/{name}/valid`` (bool, chunked by
  :data:`SERIES_CHUNK`) is created at the first line :meth:`RunFileWriter.append` is told is
  invalid, its earlier rows true, and grows with the scans from then on: a run whose lines
  are all valid does not have it. ``/encoder/time_s`` and ``/encoder/position_m`` (float64)
  are created by the first :meth:`RunFileWriter.append_encoder`.
* **Recording state.** The file is created with the root attribute ``complete = False``;
  :meth:`RunFileWriter.close` writes ``completed_scans`` (the number of scans) and
  ``completed_at`` (ISO 8601 UTC), then ``complete = True``. Leaving the ``with`` block by an
  exception (:meth:`RunFileWriter.abort`) leaves ``complete = False``, so the run reads as
  interrupted.

Reading
-------
:func:`open_run` validates the layout and returns a :class:`RunFile` whose
:meth:`RunFile.blocks` streams :class:`~catenary.domain.ScanBlock` s, never holding more than
one block (plus one chunk of each vehicle dataset). Layout errors raise
:class:`~catenary.errors.FormatError` naming the file, the HDF5 path and the value.

* **Recording state** (FORMATS.md, optional attributes). ``complete = True`` (or, in files
  of this project's recorder written before ``complete`` existed, ``completed_scans`` alone):
  the run is read up to ``completed_scans``; a ``/scans/*`` or ``/cameras/*/lines`` dataset
  holding fewer rows, or ``/vehicle/*`` datasets of unequal lengths, make a malformed file
  (FormatError), as do ``complete = True`` without ``completed_scans`` and ``complete =
  False`` with it. ``complete = False`` (the recording was interrupted, e.g. the recording PC
  lost power): datasets may differ in length, and the run is read up to the last scan that
  every scan dataset has (and the vehicle samples that all four vehicle datasets have), with
  one :class:`RunFileWarning` naming the file and the usable scans. No ``complete`` and no
  ``completed_scans`` (another recorder, or an interrupted recording of this project's
  before ``complete`` existed: they cannot be told apart): nothing is known, and the file is
  read without a warning unless its datasets differ in length (then read as an interrupted
  one, with one warning naming the lengths).
* **Vehicle sensors.** They are read in chunks as the scans advance
  (:class:`catenary.measurement.sensors.SensorStream`), optionally smoothed without phase lag
  (a :class:`~catenary.measurement.sensors.SensorSmoother`; unsmoothed by default) and
  linearly interpolated to each scan's time. ``VehicleSamples.fault`` is true for a scan before
  the first or after the last valid sensor sample (the edge sample's value is held) or lying
  inside a gap between consecutive valid samples longer than ``max_gap_factor`` (default
  :data:`DEFAULT_MAX_GAP_FACTOR` = 2.5, i.e. two or more consecutive samples missing) times
  the run's median sample interval (interpolated across the gap). A sample whose
  ``left_mm``, ``right_mm`` or ``lateral_mm`` is not finite records a faulty or missing
  reading (a recorder's flag): every scan between the valid samples either side of it is a
  fault, whatever the gap's length. With no valid
  sample at all every scan is a fault and the values are 0 (nominal ride). Values where
  ``fault`` is true are a best guess and must not be trusted.
* **Invalid lines.** A camera's ``valid`` dataset (FORMATS.md), where present, must be bool
  ``[N]`` like the scans (else a FormatError naming it) and counts among the scan datasets
  for the recording state; its rows come with the lines (``CameraLines.valid``), None where
  the file has none (every line valid). ``/encoder/*`` is not read here (the recorder writes
  it; processing uses the scans' positions).
* Unknown extra groups and attributes are ignored; any HDF5 standard filter h5py can decode
  (gzip, lzf, szip, shuffle, fletcher32, ...) is read transparently.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from collections.abc import Callable, Iterator, Mapping
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any, Final, Self

import h5py
import numpy as np
from numpy.typing import ArrayLike

from catenary.arrays import BoolArray, FloatArray, UInt8Array, UInt16Array
from catenary.domain import DEFAULT_BLOCK_SCANS, CameraLines, RunHeader, ScanBlock, VehicleSamples
from catenary.errors import FormatError, UserError
from catenary.measurement.sensors import SensorSmoother, SensorStream
from catenary.text import control_character_problem

__all__ = [
    "DEFAULT_COMPRESSION",
    "DEFAULT_GZIP_LEVEL",
    "DEFAULT_MAX_GAP_FACTOR",
    "FORMAT",
    "FORMAT_VERSION",
    "SERIES_CHUNK",
    "RunFile",
    "RunFileReader",
    "RunFileWarning",
    "RunFileWriter",
    "chunk_rows_for",
    "open_run",
]

FORMAT: Final = "catenary-run"
FORMAT_VERSION: Final = 1
DIRECTIONS: Final = ("increasing", "decreasing")
COMPLETE_ATTR: Final = "complete"
COMPLETED_ATTR: Final = "completed_scans"
COMPLETED_AT_ATTR: Final = "completed_at"

DEFAULT_COMPRESSION: Final[str | None] = None
DEFAULT_GZIP_LEVEL: Final = 1
DEFAULT_MAX_GAP_FACTOR: Final = 2.5
DEFAULT_FLUSH_INTERVAL_S: Final = 1.0

SERIES_CHUNK: Final = 65536
"""Chunk length of the 1-D datasets (``/scans/*``, ``/vehicle/*``): 512 KiB of float64."""
_VEHICLE_STAGE: Final = 4096  # vehicle samples staged before writing
_CHUNK_TARGET_BYTES: Final = 2 * 1024 * 1024
_VALIDATE_SLICE: Final = 262144  # samples read at a time when checking a 1-D dataset on open
_CACHE_CAP_BYTES: Final = 256 * 1024 * 1024
_ATTR_MAX_VALUES: Final = 64  # an attribute holding more is refused before it is read

_SCAN_SERIES: Final = ("position_m", "time_s")
_VEHICLE_SERIES: Final = ("time_s", "left_mm", "right_mm", "lateral_mm")
_ENCODER_SERIES: Final = ("time_s", "position_m")

LinesArray = UInt8Array | UInt16Array
_Columns = Mapping[str, np.ndarray[Any, Any]]


class RunFileWarning(UserWarning):
    """A run file is readable but not as recorded: e.g. the recording was interrupted."""


def _utc_now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _dtype_for_bit_depth(bit_depth: int) -> np.dtype[np.uint8] | np.dtype[np.uint16]:
    return np.dtype(np.uint8) if bit_depth <= 8 else np.dtype(np.uint16)


def chunk_rows_for(row_bytes: int, target_bytes: int = _CHUNK_TARGET_BYTES) -> int:
    """Rows per chunk for rows of ``row_bytes``: the largest power of two with
    ``rows * row_bytes <= target_bytes`` (at least 1), so a chunk is 1-2 MiB by default."""
    if row_bytes <= 0:
        raise ValueError(f"row_bytes must be positive, got {row_bytes}")
    rows = max(1, target_bytes // row_bytes)
    return 1 << (rows.bit_length() - 1)


def _cache_kwargs(chunk_bytes: int, filtered: bool) -> dict[str, Any]:
    """The chunk cache of a dataset streamed along its first axis.

    Filtered (compressed) chunks: room for two chunks, fully read/written chunks evicted
    first, so that a block straddling chunks decompresses each chunk once. Unfiltered
    chunks: no cache, so HDF5 reads and writes straight between the file and the array
    (measured 2x faster than going through the cache).
    """
    if not filtered:
        return {"rdcc_nbytes": 0, "rdcc_w0": 1.0, "rdcc_nslots": 1}
    nbytes = min(_CACHE_CAP_BYTES, 2 * chunk_bytes + 1024)
    return {"rdcc_nbytes": nbytes, "rdcc_w0": 1.0, "rdcc_nslots": 521}


# --------------------------------------------------------------------------------------------
# Writing


class _GrowingDatasets:
    """Datasets that grow together along their first axis, small appends staged in memory.

    Appends smaller than ``stage_rows`` (in total) are copied and held; a larger one writes
    what is held, then itself, straight to the file. Every dataset is written at the same
    ``committed`` index, so a failed write can be retried without misaligning them.
    """

    def __init__(self, datasets: Mapping[str, Any], stage_rows: int) -> None:
        self.datasets = dict(datasets)
        self.stage_rows = stage_rows
        self.committed = 0
        self._parts: dict[str, list[np.ndarray[Any, Any]]] = {key: [] for key in datasets}
        self._staged = 0

    def add(self, key: str, ds: Any) -> None:
        """Grow ``ds`` with the others from now on (after a :meth:`commit`: nothing staged);
        written first, so a write cut short leaves it no shorter than the rest."""
        assert self._staged == 0 and ds.shape[0] == self.committed
        self.datasets = {key: ds, **self.datasets}
        self._parts = {key: [], **self._parts}

    def append(self, columns: _Columns, n: int) -> None:
        if self._staged + n < self.stage_rows:
            for key in self.datasets:
                self._parts[key].append(np.array(columns[key], copy=True))
            self._staged += n
            return
        self.commit()
        self._write(columns, n)

    def commit(self) -> None:
        """Write what is staged."""
        if self._staged == 0:
            return
        columns = {
            key: parts[0] if len(parts) == 1 else np.concatenate(parts)
            for key, parts in self._parts.items()
        }
        self._write(columns, self._staged)
        for parts in self._parts.values():
            parts.clear()
        self._staged = 0

    def _write(self, columns: _Columns, n: int) -> None:
        start = self.committed
        stop = start + n
        for key, ds in self.datasets.items():
            ds.resize(stop, axis=0)
            ds[start:stop] = columns[key]
        self.committed = stop


class RunFileWriter:
    """Write a recorded run file (FORMATS.md) block by block; a context manager.

    Parameters
    ----------
    path : str or Path
        The ``*.h5`` file to create. An existing file is an error unless ``overwrite``.
    line, track, vehicle : str
        Identifiers (may be empty).
    direction : str
        ``"increasing"`` or ``"decreasing"`` chainage.
    start_chainage_m : float
        Chainage at the first scan, as known at the start [m].
    scan_rate_hz : float
        Nominal camera trigger rate [Hz], positive.
    cameras : mapping of name to ``(pixels, bit_depth)``
        At least one camera; ``bit_depth`` 1-16. Lines are uint8 for ``bit_depth <= 8`` and
        uint16 above; ``pixels`` is the width ``W`` of the lines recorded.
    offsets_px : mapping of name to int, optional
        The cameras that record a region of interest: the sensor pixel of their lines' first
        pixel (``/cameras/{name}`` attribute ``offset_px``, >= 0).
    started_at : str, optional
        ISO 8601 UTC wall-clock time of the first scan; default: now.
    compression : {"gzip", "lzf", "szip", None}
        HDF5 filter for every dataset; default :data:`DEFAULT_COMPRESSION` (see the module
        docstring for why). ``compression_opts`` is passed to h5py (gzip level, default
        :data:`DEFAULT_GZIP_LEVEL`; szip ``("nn", 8)`` by default).
    shuffle : bool, optional
        Byte-shuffle before compressing; default: on whenever ``compression`` is set.
    fletcher32 : bool
        Add a checksum to every chunk.
    chunk_scans : int, optional
        Rows per chunk of every camera's lines; default :func:`chunk_rows_for` of the line
        size (1-2 MiB per chunk).
    flush_interval_s : float
        Write staged scans and flush the HDF5 file on the first append this long after the
        last flush [s] (0: on every append).
    overwrite : bool
        Replace an existing file.

    Invalid input raises :class:`ValueError` naming the file and the field before anything of
    that call is written.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        line: str = "",
        track: str = "",
        vehicle: str = "",
        direction: str = "increasing",
        start_chainage_m: float = 0.0,
        scan_rate_hz: float,
        cameras: Mapping[str, tuple[int, int]],
        offsets_px: Mapping[str, int] | None = None,
        started_at: str | None = None,
        compression: str | None = DEFAULT_COMPRESSION,
        compression_opts: Any = None,
        shuffle: bool | None = None,
        fletcher32: bool = False,
        chunk_scans: int | None = None,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        self._validate_header(
            line, track, vehicle, direction, start_chainage_m, scan_rate_hz, started_at
        )
        self._cameras = self._validate_cameras(cameras)
        self._offsets_px = dict(offsets_px or {})
        for name, offset in self._offsets_px.items():
            if name not in self._cameras:
                raise self._error(f"offsets_px: unknown camera {name!r}")
            if not _is_int(offset) or offset < 0:
                raise self._error(
                    f"camera {name!r}: offset_px must be an integer >= 0, got {offset!r}"
                )
        if chunk_scans is not None and (
            isinstance(chunk_scans, bool) or not isinstance(chunk_scans, int) or chunk_scans < 1
        ):
            raise self._error(f"chunk_scans must be a positive integer, got {chunk_scans!r}")
        if compression not in (None, "gzip", "lzf", "szip"):
            raise self._error(f"compression must be gzip, lzf, szip or None, got {compression!r}")
        if compression == "gzip" and compression_opts is None:
            compression_opts = DEFAULT_GZIP_LEVEL
        if compression == "szip" and compression_opts is None:
            compression_opts = ("nn", 8)
        filters: dict[str, Any] = {
            "compression": compression,
            "compression_opts": compression_opts,
            "shuffle": (compression is not None) if shuffle is None else bool(shuffle),
            "fletcher32": bool(fletcher32),
        }
        if not (math.isfinite(flush_interval_s) and flush_interval_s >= 0.0):
            raise self._error(f"flush_interval_s must be >= 0, got {flush_interval_s!r}")
        self._flush_interval_s = float(flush_interval_s)

        try:
            self._file = h5py.File(self.path, "w" if overwrite else "w-")
        except FileExistsError:
            raise UserError(f"{self.path}: already exists (not overwritten)") from None
        except OSError as exc:
            if self.path.exists() and not overwrite:
                raise UserError(f"{self.path}: already exists (not overwritten)") from None
            raise UserError(f"{self.path}: cannot create run file ({exc})") from None
        try:
            self._create_layout(
                {
                    "format": FORMAT,
                    "format_version": np.int64(FORMAT_VERSION),
                    "line": line,
                    "track": track,
                    "vehicle": vehicle,
                    "direction": direction,
                    "start_chainage_m": np.float64(start_chainage_m),
                    "started_at": started_at if started_at is not None else _utc_now_iso(),
                    "scan_rate_hz": np.float64(scan_rate_hz),
                    COMPLETE_ATTR: False,
                },
                filters,
                chunk_scans,
            )
        except BaseException:
            self._file.close()
            raise
        self._scans = 0
        self._vehicle_samples = 0
        self._encoder_readings = 0
        self._invalid_lines = dict.fromkeys(self._cameras, 0)
        self._encoder_data: _GrowingDatasets | None = None
        self._last_encoder_time_s = -math.inf
        self._last_position_m = -math.inf
        self._last_time_s = -math.inf
        self._last_vehicle_time_s = -math.inf
        self._last_flush = time.monotonic()
        self._closed = False

    # -- set-up ---------------------------------------------------------------------------

    def _error(self, problem: str) -> ValueError:
        return ValueError(f"{self.path}: {problem}")

    def _validate_header(
        self,
        line: str,
        track: str,
        vehicle: str,
        direction: str,
        start_chainage_m: float,
        scan_rate_hz: float,
        started_at: str | None,
    ) -> None:
        for name, value in (("line", line), ("track", track), ("vehicle", vehicle)):
            if not isinstance(value, str):
                raise self._error(f"{name} must be a string, got {value!r}")
        if direction not in DIRECTIONS:
            raise self._error(f"direction must be 'increasing' or 'decreasing', got {direction!r}")
        if not _is_real(start_chainage_m) or not math.isfinite(start_chainage_m):
            raise self._error(f"start_chainage_m must be a finite number, got {start_chainage_m!r}")
        if not _is_real(scan_rate_hz) or not (math.isfinite(scan_rate_hz) and scan_rate_hz > 0):
            raise self._error(f"scan_rate_hz must be a positive number, got {scan_rate_hz!r}")
        if started_at is not None and not _is_iso8601(started_at):
            raise self._error(f"started_at must be an ISO 8601 time, got {started_at!r}")

    def _validate_cameras(
        self, cameras: Mapping[str, tuple[int, int]]
    ) -> dict[str, tuple[int, int]]:
        if not cameras:
            raise self._error("at least one camera is needed")
        checked: dict[str, tuple[int, int]] = {}
        for name, spec in cameras.items():
            if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
                raise self._error(
                    f"camera name must be a non-empty string without '/', got {name!r}"
                )
            try:
                pixels, bit_depth = spec
            except (TypeError, ValueError):
                raise self._error(
                    f"camera {name!r}: expected (pixels, bit_depth), got {spec!r}"
                ) from None
            if not _is_int(pixels) or pixels < 1:
                raise self._error(
                    f"camera {name!r}: pixels must be a positive integer, got {pixels!r}"
                )
            if not _is_int(bit_depth) or not 1 <= bit_depth <= 16:
                raise self._error(f"camera {name!r}: bit_depth must be 1-16, got {bit_depth!r}")
            checked[name] = (int(pixels), int(bit_depth))
        return checked

    def _create_layout(
        self, attrs: dict[str, Any], filters: dict[str, Any], chunk_scans: int | None
    ) -> None:
        f = self._file
        for key, value in attrs.items():
            f.attrs[key] = value
        filtered = bool(filters["compression"] or filters["shuffle"] or filters["fletcher32"])
        series = {
            "shape": (0,),
            "maxshape": (None,),
            "dtype": np.float64,
            "chunks": (SERIES_CHUNK,),
            **filters,
            **_cache_kwargs(SERIES_CHUNK * 8, filtered),
        }
        self._series_options = series  # for /encoder/* and, as bool, /cameras/*/valid
        self._flag_cache = _cache_kwargs(SERIES_CHUNK, filtered)
        # Lines first: a write cut short leaves positions no longer than the lines.
        scan_datasets: dict[str, Any] = {}
        stage_rows = SERIES_CHUNK
        for name, (pixels, bit_depth) in self._cameras.items():
            dtype = _dtype_for_bit_depth(bit_depth)
            rows = chunk_scans or chunk_rows_for(pixels * dtype.itemsize)
            stage_rows = min(stage_rows, rows)
            ds = f.create_dataset(
                f"cameras/{name}/lines",
                shape=(0, pixels),
                maxshape=(None, pixels),
                dtype=dtype,
                chunks=(rows, pixels),
                **filters,
                **_cache_kwargs(rows * pixels * dtype.itemsize, filtered),
            )
            ds.attrs["bit_depth"] = np.int64(bit_depth)
            if name in self._offsets_px:
                f[f"cameras/{name}"].attrs["offset_px"] = np.int64(self._offsets_px[name])
            scan_datasets[f"cameras/{name}/lines"] = ds
        for name in _SCAN_SERIES:
            scan_datasets[f"scans/{name}"] = f.create_dataset(f"scans/{name}", **series)
        vehicle_datasets = {
            name: f.create_dataset(f"vehicle/{name}", **series) for name in _VEHICLE_SERIES
        }
        f.flush()
        self._scan_data = _GrowingDatasets(scan_datasets, stage_rows)
        self._vehicle_data = _GrowingDatasets(vehicle_datasets, _VEHICLE_STAGE)

    # -- appending ------------------------------------------------------------------------

    @property
    def scans(self) -> int:
        """Scans appended so far (staged ones included)."""
        return self._scans

    @property
    def vehicle_samples(self) -> int:
        """Vehicle sensor samples appended so far (staged ones included)."""
        return self._vehicle_samples

    @property
    def encoder_readings(self) -> int:
        """Encoder readings appended so far (staged ones included)."""
        return self._encoder_readings

    @property
    def invalid_lines(self) -> dict[str, int]:
        """Per camera, the lines appended marked invalid so far."""
        return dict(self._invalid_lines)

    @property
    def closed(self) -> bool:
        return self._closed

    def append(
        self,
        block_positions_m: ArrayLike,
        time_s: ArrayLike,
        lines: Mapping[str, LinesArray],
        valid: Mapping[str, ArrayLike | None] | None = None,
    ) -> None:
        """Append a block of ``n`` scans.

        Parameters
        ----------
        block_positions_m : array_like ``[n]``
            Encoder distance since the first scan [m]: finite, non-decreasing, continuing the
            previous blocks.
        time_s : array_like ``[n]``
            Seconds since the first scan: finite, non-decreasing.
        lines : mapping of camera name to ndarray ``[n, W]``
            One line per scan for every camera given to the constructor, of exactly its dtype
            (uint8 for ``bit_depth <= 8``, else uint16) and width, every value below
            ``2**bit_depth``.
        valid : mapping of camera name to bool array_like ``[n]`` (or None), optional
            False where the camera delivered no line for the scan (its line's pixels are
            meaningless); a camera not given (or None): every line valid. The dataset
            ``/cameras/{name}/valid`` is created at the first invalid line (earlier rows
            true), so a run whose lines are all valid does not have it.

        The arrays are copied or written before this returns; the caller may reuse them.
        """
        self._check_open()
        position = _as_series(block_positions_m)
        if position is None:
            raise self._error("append: block_positions_m must be a 1-D array of numbers")
        times = _as_series(time_s)
        if times is None:
            raise self._error("append: time_s must be a 1-D array of numbers")
        n = position.shape[0]
        if times.shape[0] != n:
            raise self._error(
                f"append: time_s has {times.shape[0]} values but block_positions_m has {n}"
            )
        self._check_lines(lines, n)
        flags = self._check_valid(valid or {}, n)
        if n == 0:
            return
        first = self._scans
        _check_monotonic(position, self._last_position_m, "block_positions_m", first, self._error)
        _check_monotonic(times, self._last_time_s, "time_s", first, self._error)

        for name, flag in flags.items():
            lost = n - int(np.count_nonzero(flag))
            key = f"cameras/{name}/valid"
            if lost and key not in self._scan_data.datasets:
                self._create_valid(key)
            self._invalid_lines[name] += lost
        columns: dict[str, np.ndarray[Any, Any]] = {
            "scans/position_m": position,
            "scans/time_s": times,
        }
        columns.update((f"cameras/{name}/lines", lines[name]) for name in self._cameras)
        for name in self._cameras:
            key = f"cameras/{name}/valid"
            if key in self._scan_data.datasets:
                columns[key] = flags[name] if name in flags else np.ones(n, dtype=bool)
        self._scan_data.append(columns, n)
        self._scans += n
        self._last_position_m = float(position[-1])
        self._last_time_s = float(times[-1])
        self._maybe_flush()

    def append_vehicle(
        self,
        time_s: ArrayLike,
        left_mm: ArrayLike,
        right_mm: ArrayLike,
        lateral_mm: ArrayLike,
    ) -> None:
        """Append ``k`` vehicle sensor samples, each argument ``[k]`` (or a scalar for one).

        ``time_s`` is on the scan clock, finite and non-decreasing across calls. A sensor
        value that is NaN records a missing reading (the reader treats it as a gap).
        """
        self._check_open()
        arrays: list[FloatArray] = []
        for name, value in zip(
            _VEHICLE_SERIES, (time_s, left_mm, right_mm, lateral_mm), strict=True
        ):
            series = _as_series(np.atleast_1d(np.asarray(value)) if np.ndim(value) == 0 else value)
            if series is None:
                raise self._error(f"append_vehicle: {name} must be a 1-D array of numbers")
            arrays.append(series)
        k = arrays[0].shape[0]
        for name, series in zip(_VEHICLE_SERIES, arrays, strict=True):
            if series.shape[0] != k:
                raise self._error(
                    f"append_vehicle: {name} has {series.shape[0]} values but time_s has {k}"
                )
        if k == 0:
            return
        for name, series in zip(_VEHICLE_SERIES[1:], arrays[1:], strict=True):
            if np.isinf(series).any():
                raise self._error(f"append_vehicle: {name} is infinite")
        _check_monotonic(
            arrays[0],
            self._last_vehicle_time_s,
            "vehicle time_s",
            self._vehicle_samples,
            self._error,
        )
        self._vehicle_data.append(dict(zip(_VEHICLE_SERIES, arrays, strict=True)), k)
        self._vehicle_samples += k
        self._last_vehicle_time_s = float(arrays[0][-1])
        self._maybe_flush()

    def _check_valid(self, valid: Mapping[str, ArrayLike | None], n: int) -> dict[str, BoolArray]:
        """The ``valid`` flags given, each a bool array ``[n]``."""
        flags: dict[str, BoolArray] = {}
        for name, value in valid.items():
            if name not in self._cameras:
                raise self._error(f"append: valid of unknown camera {name!r}")
            if value is None:
                continue
            flag = np.asarray(value)
            if flag.dtype != np.bool_ or flag.shape != (n,):
                raise self._error(
                    f"append: valid of camera {name!r} is {flag.dtype} {flag.shape}, "
                    f"expected bool ({n},)"
                )
            flags[name] = flag
        return flags

    def _create_valid(self, key: str) -> None:
        """``/cameras/{name}/valid``, its rows so far true, growing with the scans."""
        self._scan_data.commit()
        rows = self._scan_data.committed
        options = {**self._series_options, **self._flag_cache, "shape": (rows,)}
        ds = self._file.create_dataset(key, **{**options, "dtype": np.bool_})
        if rows:
            ds[:] = True  # stored, not a fill value: a reader checks the rows a file holds
        self._scan_data.add(key, ds)

    def append_encoder(self, time_s: ArrayLike, position_m: ArrayLike) -> None:
        """Append ``e`` wheel encoder readings (``/encoder/time_s``, ``/encoder/position_m``),
        each ``[e]``: times on the scan clock, finite and non-decreasing across calls;
        positions finite [m]. The datasets are created at the first call."""
        self._check_open()
        times = _as_series(time_s)
        position = _as_series(position_m)
        if times is None or position is None or times.shape != position.shape:
            raise self._error(
                "append_encoder: time_s and position_m must be 1-D arrays of numbers of one length"
            )
        if self._encoder_data is None:
            datasets = {
                name: self._file.create_dataset(f"encoder/{name}", **self._series_options)
                for name in _ENCODER_SERIES
            }
            self._encoder_data = _GrowingDatasets(datasets, _VEHICLE_STAGE)
        e = times.shape[0]
        if e == 0:
            return
        _check_monotonic(
            times, self._last_encoder_time_s, "encoder time_s", self._encoder_readings, self._error
        )
        bad = ~np.isfinite(position)
        if bad.any():
            i = int(np.argmax(bad))
            raise self._error(
                f"append_encoder: position_m[{self._encoder_readings + i}] is {position[i]}, "
                "not finite"
            )
        self._encoder_data.append({"time_s": times, "position_m": position}, e)
        self._encoder_readings += e
        self._last_encoder_time_s = float(times[-1])
        self._maybe_flush()

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: run file writer is closed")

    def _check_lines(self, lines: Mapping[str, LinesArray], n: int) -> None:
        missing = sorted(set(self._cameras) - set(lines))
        if missing:
            raise self._error(f"append: no lines for camera(s) {', '.join(missing)}")
        extra = sorted(set(lines) - set(self._cameras))
        if extra:
            raise self._error(f"append: unknown camera(s) {', '.join(map(str, extra))}")
        for name, (pixels, bit_depth) in self._cameras.items():
            block = lines[name]
            dtype = _dtype_for_bit_depth(bit_depth)
            if not isinstance(block, np.ndarray):
                raise self._error(f"append: lines of camera {name!r} must be a NumPy array")
            if block.dtype != dtype:
                raise self._error(
                    f"append: lines of camera {name!r} are {block.dtype}, expected {dtype} "
                    f"for bit_depth {bit_depth}"
                )
            if block.shape != (n, pixels):
                raise self._error(
                    f"append: lines of camera {name!r} have shape {block.shape}, "
                    f"expected ({n}, {pixels})"
                )
            if n and bit_depth not in (8, 16):
                peak = int(block.max())
                if peak >= 1 << bit_depth:
                    raise self._error(
                        f"append: lines of camera {name!r} hold {peak}, above the "
                        f"{bit_depth}-bit maximum {(1 << bit_depth) - 1}"
                    )

    def _maybe_flush(self) -> None:
        if time.monotonic() - self._last_flush >= self._flush_interval_s:
            self.flush()

    def _commit(self) -> None:
        self._scan_data.commit()
        self._vehicle_data.commit()
        if self._encoder_data is not None:
            self._encoder_data.commit()

    def flush(self) -> None:
        """Write staged scans and samples and flush the HDF5 file to the operating system."""
        self._check_open()
        self._commit()
        self._file.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write everything staged, ``complete = True`` with ``completed_scans`` and
        ``completed_at``, and close. Idempotent."""
        if self._closed:
            return
        try:
            self._commit()
            self._file.attrs[COMPLETED_AT_ATTR] = _utc_now_iso()
            self._file.attrs[COMPLETED_ATTR] = np.int64(self._scans)
            self._file.attrs[COMPLETE_ATTR] = True  # last: a crash before it reads interrupted
        finally:
            self._closed = True
            self._file.close()

    def abort(self) -> None:
        """Write what is staged and close leaving ``complete = False`` (an interrupted run)."""
        if self._closed:
            return
        try:
            self._commit()
        finally:
            self._closed = True
            self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _show(value: object) -> str:
    """``repr`` of an attribute value as a user would write it (no ``np.int64(...)``)."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, np.ndarray):
        value = value.tolist()
    return repr(value)


def _is_real(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def _is_iso8601(value: object) -> bool:
    if not isinstance(value, str):
        return False
    try:
        datetime.fromisoformat(value)
    except ValueError:
        return False
    return True


def _as_series(values: ArrayLike) -> FloatArray | None:
    """``values`` as a 1-D float64 array, or None if it is not one."""
    try:
        array = np.asarray(values)
    except (TypeError, ValueError):
        return None
    if array.ndim != 1 or not (array.dtype.kind in "fiu" or array.size == 0):
        return None
    return np.asarray(array, dtype=np.float64)


def _check_monotonic(
    values: FloatArray, previous: float, name: str, first: int, error: Any
) -> None:
    """Finite and non-decreasing, continuing from ``previous``; ``first`` numbers the values."""
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.argmax(bad))
        raise error(f"{name}[{first + i}] is {values[i]}, not finite")
    if values[0] < previous:
        raise error(f"{name} decreases at {first}: {previous!r} -> {float(values[0])!r}")
    drops = np.diff(values) < 0
    if drops.any():
        i = int(np.argmax(drops))
        raise error(
            f"{name} decreases at {first + i + 1}: {float(values[i])!r} -> {float(values[i + 1])!r}"
        )


# --------------------------------------------------------------------------------------------
# Reading


def open_run(path: str | Path) -> RunFile:
    """Open and validate a recorded run file; see :class:`RunFile`."""
    return RunFile(path, _caller_depth=2)


class RunFile:
    """A recorded run file opened for reading (also exported as ``RunFileReader``).

    Opening validates the whole layout (streaming the 1-D datasets to check that positions
    and times are finite and non-decreasing) and raises :class:`FormatError` naming the file,
    the HDF5 path and the value when it is wrong, or warns :class:`RunFileWarning` when the
    recording was interrupted (module docstring). Use as a context manager, or ``close()``.

    Attributes
    ----------
    path : Path
    header : RunHeader
        Root attributes; ``scans`` is the number of usable scans.
    complete : bool or None
        The recording state: True closed properly, False interrupted, None unknown (another
        recorder: no ``complete`` attribute nor ``completed_scans``).
    vehicle_samples : int
        Usable vehicle sensor samples ``K``.
    vehicle_interval_s : float or None
        Median interval between vehicle samples (None with fewer than two distinct times).
    """

    def __init__(self, path: str | Path, *, _caller_depth: int = 1) -> None:
        self.path = Path(path)
        self._caller_depth = _caller_depth  # stack frames up to the user, for warnings
        if not self.path.exists():
            raise UserError(f"{self.path}: no such file")
        if not self.path.is_file():
            raise UserError(f"{self.path}: not a file")
        try:
            self._file = h5py.File(self.path, "r")
        except OSError as exc:
            raise FormatError(self.path, f"not a readable HDF5 file ({_reason(exc)})") from None
        try:
            self._open()
        except _DAMAGED as exc:
            self._file.close()
            if isinstance(exc, FormatError):
                raise
            raise FormatError(self.path, f"damaged HDF5 file ({_reason(exc)})") from None
        except BaseException:
            self._file.close()
            raise

    # -- validation -----------------------------------------------------------------------

    def _fail(self, problem: str) -> FormatError:
        return FormatError(self.path, problem)

    def _open(self) -> None:
        fmt = self._attr_str("format")
        if fmt != FORMAT:
            raise self._fail(f"/ attribute format = {fmt!r}, expected {FORMAT!r}")
        version = self._attr("format_version")
        if not _is_int(version):
            raise self._fail(f"/ attribute format_version = {_show(version)}, expected an integer")
        if int(version) != FORMAT_VERSION:
            raise self._fail(
                f"/ attribute format_version = {int(version)}: unknown version "
                f"(this version of catenary reads format_version {FORMAT_VERSION})"
            )
        line = self._attr_identifier("line")
        track = self._attr_identifier("track")
        vehicle = self._attr_identifier("vehicle")
        direction = self._attr_str("direction")
        if direction not in DIRECTIONS:
            raise self._fail(
                f"/ attribute direction = {direction!r}, expected 'increasing' or 'decreasing'"
            )
        start_chainage_m = self._attr_float("start_chainage_m")
        started_at = self._attr_str("started_at")
        if not _is_iso8601(started_at):
            raise self._fail(f"/ attribute started_at = {started_at!r}, not an ISO 8601 time")
        scan_rate_hz = self._attr_float("scan_rate_hz")
        if scan_rate_hz <= 0:
            raise self._fail(f"/ attribute scan_rate_hz = {scan_rate_hz!r}, not positive")

        self._series = {name: self._dataset_1d(f"/scans/{name}") for name in _SCAN_SERIES}
        self._lines, bit_depths, offsets = self._camera_datasets()
        self._valid = self._valid_datasets()
        self._vehicle = {name: self._dataset_1d(f"/vehicle/{name}") for name in _VEHICLE_SERIES}

        lengths = {f"/scans/{name}": int(ds.shape[0]) for name, ds in self._series.items()}
        lengths.update(
            (f"/cameras/{name}/lines", int(ds.shape[0])) for name, ds in self._lines.items()
        )
        lengths.update(
            (f"/cameras/{name}/valid", int(ds.shape[0])) for name, ds in self._valid.items()
        )
        vehicle_lengths = {
            f"/vehicle/{name}": int(ds.shape[0]) for name, ds in self._vehicle.items()
        }
        scans, samples = self._recording_state(lengths, vehicle_lengths)
        for where, ds in self._series.items():
            self._check_held(ds, f"/scans/{where}", scans)
        for where, ds in self._lines.items():
            self._check_held(ds, f"/cameras/{where}/lines", scans)
        for where, ds in self._valid.items():
            self._check_held(ds, f"/cameras/{where}/valid", scans)
        for where, ds in self._vehicle.items():
            self._check_held(ds, f"/vehicle/{where}", samples)
        self._check_series(self._series["position_m"], "/scans/position_m", scans)
        self._check_series(self._series["time_s"], "/scans/time_s", scans)
        self.vehicle_interval_s = self._check_series(
            self._vehicle["time_s"], "/vehicle/time_s", samples, median_step=True
        )
        self.vehicle_samples = samples
        self.header = RunHeader(
            line=line,
            track=track,
            vehicle=vehicle,
            direction=direction,
            start_chainage_m=start_chainage_m,
            started_at=started_at,
            scan_rate_hz=scan_rate_hz,
            scans=scans,
            camera_pixels={name: int(ds.shape[1]) for name, ds in self._lines.items()},
            camera_bit_depth=bit_depths,
            camera_offset_px=offsets,
        )

    def _recording_state(
        self, lengths: dict[str, int], vehicle_lengths: dict[str, int]
    ) -> tuple[int, int]:
        """The usable scans and vehicle samples from the recording state (module docstring);
        sets ``complete`` and warns once where the file is interrupted or its datasets
        differ in length."""
        complete = self._attr_state()
        marker = self._file.attrs.get(COMPLETED_ATTR)
        if marker is not None:
            if not _is_int(marker) or int(marker) < 0:
                raise self._fail(
                    f"/ attribute {COMPLETED_ATTR} = {_show(marker)}, expected a count of scans"
                )
            if complete is False:
                raise self._fail(
                    f"/ attribute {COMPLETE_ATTR} = False contradicts "
                    f"{COMPLETED_ATTR} = {int(marker)} (written only with {COMPLETE_ATTR} = True)"
                )
        elif complete:
            raise self._fail(f"/ attribute {COMPLETE_ATTR} = True without {COMPLETED_ATTR}")
        if marker is not None:  # complete = True, or the marker alone (before `complete`)
            self.complete: bool | None = True
            for where, length in lengths.items():
                if length < int(marker):
                    raise self._fail(
                        f"{where} has {length} scans but the file is marked complete with "
                        f"{COMPLETED_ATTR} = {int(marker)} (lengths: "
                        + ", ".join(f"{w} {n}" for w, n in lengths.items())
                        + ")"
                    )
            if len(set(vehicle_lengths.values())) > 1:
                raise self._fail(
                    "mismatched lengths of the vehicle datasets in a complete file: "
                    + ", ".join(f"{w} {n}" for w, n in vehicle_lengths.items())
                )
            return int(marker), next(iter(vehicle_lengths.values()))
        self.complete = complete
        scans = min(lengths.values())
        samples = min(vehicle_lengths.values())
        detail = []
        if len(set(lengths.values())) > 1:
            detail += [f"{w} {n}" for w, n in lengths.items()]
        if len(set(vehicle_lengths.values())) > 1:
            detail += [f"{w} {n}" for w, n in vehicle_lengths.items()]
        if complete is None and not detail:
            return scans, samples  # nothing known and nothing amiss: no warning
        what = (
            f"/ attribute {COMPLETE_ATTR} = False: the recording was interrupted"
            if complete is False
            else "datasets of different lengths"
        )
        warnings.warn(
            f"{self.path}: {what}; reading the {scans} scans and {samples} vehicle samples "
            "that every dataset has" + (f" (lengths: {', '.join(detail)})" if detail else ""),
            RunFileWarning,
            stacklevel=3 + self._caller_depth,
        )
        return scans, samples

    def _attr_state(self) -> bool | None:
        """The root attribute ``complete`` (a bool, or the integer 0 or 1), None if absent."""
        if COMPLETE_ATTR not in self._file.attrs:
            return None
        value = self._attr(COMPLETE_ATTR)
        if isinstance(value, np.ndarray) and value.shape == (1,):
            value = value[0]
        if isinstance(value, bool | np.bool_) or (_is_int(value) and int(value) in (0, 1)):
            return bool(value)
        raise self._fail(f"/ attribute {COMPLETE_ATTR} = {_show(value)}, expected true or false")

    def _attr(self, name: str, where: str = "/") -> Any:
        attrs = self._file[where].attrs
        try:
            if name not in attrs:
                raise self._fail(f"{where} attribute {name} is missing")
            values = math.prod(attrs.get_id(name).shape or ())
            if values > _ATTR_MAX_VALUES:  # read nothing of it: its size may be forged
                raise self._fail(f"{where} attribute {name} holds {values} values, expected one")
            return attrs[name]
        except (*_DAMAGED, TypeError, ValueError) as exc:
            if isinstance(exc, FormatError):
                raise
            raise self._fail(f"{where} attribute {name} cannot be read ({_reason(exc)})") from None

    def _attr_str(self, name: str) -> str:
        value = self._attr(name)
        if isinstance(value, np.ndarray) and value.shape == (1,):
            value = value[0]
        if isinstance(value, bytes | np.bytes_):
            try:
                return bytes(value).decode("utf-8")
            except UnicodeDecodeError:
                raise self._fail(f"/ attribute {name} = {_show(value)}, not UTF-8 text") from None
        if isinstance(value, str):
            return value
        raise self._fail(f"/ attribute {name} = {_show(value)}, expected a string")

    def _attr_identifier(self, name: str) -> str:
        value = self._attr_str(name)
        problem = control_character_problem(f"/ attribute {name}", value)
        if problem is not None:
            raise self._fail(problem)
        return value

    def _attr_float(self, name: str) -> float:
        value = self._attr(name)
        if isinstance(value, np.ndarray) and value.shape == (1,):
            value = value[0]
        if not _is_real(value) or not math.isfinite(float(value)):
            raise self._fail(f"/ attribute {name} = {_show(value)}, expected a finite number")
        return float(value)

    def _object(self, where: str, kind: type) -> Any:
        try:
            obj = self._file.get(where)
        except (KeyError, OSError, RuntimeError) as exc:
            raise self._fail(f"{where} cannot be read ({exc})") from None
        if obj is None:
            what = "dataset" if kind is h5py.Dataset else "group"
            raise self._fail(f"{where} is missing (a {what} is required)")
        if not isinstance(obj, kind):
            what = "dataset" if kind is h5py.Dataset else "group"
            raise self._fail(f"{where} is not a {what}")
        return obj

    def _reopen_with_cache(self, ds: Any) -> Any:
        """The dataset again with the chunk cache of :func:`_cache_kwargs`."""
        if ds.chunks is None:
            return ds
        chunk_bytes = int(np.prod(ds.chunks)) * ds.dtype.itemsize
        filtered = ds.id.get_create_plist().get_nfilters() > 0
        cache = _cache_kwargs(chunk_bytes, filtered)
        dapl = h5py.h5p.create(h5py.h5p.DATASET_ACCESS)
        dapl.set_chunk_cache(cache["rdcc_nslots"], cache["rdcc_nbytes"], cache["rdcc_w0"])
        return h5py.Dataset(h5py.h5d.open(self._file.id, ds.name.encode("utf-8"), dapl))

    def _dataset_1d(self, where: str) -> Any:
        ds = self._object(where, h5py.Dataset)
        if ds.dtype.kind != "f" or ds.dtype.itemsize != 8:
            raise self._fail(f"{where} has dtype {ds.dtype}, expected float64")
        if ds.ndim != 1:
            raise self._fail(f"{where} has shape {ds.shape}, expected 1-D [N]")
        return self._reopen_with_cache(ds)

    def _camera_datasets(self) -> tuple[dict[str, Any], dict[str, int], dict[str, int]]:
        """Each camera's lines, bit depth and (where declared) ``offset_px``."""
        group = self._object("/cameras", h5py.Group)
        names = sorted(group.keys())
        if not names:
            raise self._fail("/cameras has no camera")
        lines: dict[str, Any] = {}
        bit_depths: dict[str, int] = {}
        offsets: dict[str, int] = {}
        for name in names:
            camera = self._object(f"/cameras/{name}", h5py.Group)
            if "offset_px" in camera.attrs:
                offset = self._attr("offset_px", f"/cameras/{name}")
                if isinstance(offset, np.ndarray) and offset.shape == (1,):
                    offset = offset[0]
                if not _is_int(offset) or int(offset) < 0:
                    raise self._fail(
                        f"/cameras/{name} attribute offset_px = {_show(offset)}, "
                        "expected an integer >= 0"
                    )
                offsets[name] = int(offset)
            where = f"/cameras/{name}/lines"
            ds = self._object(where, h5py.Dataset)
            bit_depth = self._attr("bit_depth", where)
            if isinstance(bit_depth, np.ndarray) and bit_depth.shape == (1,):
                bit_depth = bit_depth[0]
            if not _is_int(bit_depth) or not 1 <= int(bit_depth) <= 16:
                raise self._fail(
                    f"{where} attribute bit_depth = {_show(bit_depth)}, expected an integer 1-16"
                )
            dtype = ds.dtype
            if dtype.kind != "u" or dtype.itemsize not in (1, 2):
                raise self._fail(f"{where} has dtype {dtype}, expected uint8 or uint16")
            if dtype.itemsize == 1 and int(bit_depth) > 8:
                raise self._fail(
                    f"camera {name!r}: {where} attribute bit_depth = {int(bit_depth)} is "
                    "above the 8 bits of its dtype uint8 (needs uint16)"
                )
            if ds.ndim != 2 or ds.shape[1] < 1:
                raise self._fail(f"{where} has shape {ds.shape}, expected [N, W]")
            lines[name] = self._reopen_with_cache(ds)
            bit_depths[name] = int(bit_depth)
        return lines, bit_depths, offsets

    def _valid_datasets(self) -> dict[str, Any]:
        """The cameras' optional ``valid`` flags (FORMATS.md): bool ``[N]``."""
        valid: dict[str, Any] = {}
        for name in self._lines:
            where = f"/cameras/{name}/valid"
            if "valid" not in self._file[f"/cameras/{name}"]:
                continue
            ds = self._object(where, h5py.Dataset)
            if ds.dtype != np.bool_:
                raise self._fail(f"{where} has dtype {ds.dtype}, expected bool")
            if ds.ndim != 1:
                raise self._fail(f"{where} has shape {ds.shape}, expected 1-D [N]")
            valid[name] = self._reopen_with_cache(ds)
        return valid

    def _check_held(self, ds: Any, where: str, rows: int) -> None:
        """Refuse to read ``rows`` rows of ``ds`` unless its file stores them (``_rows_held``),
        before anything streams: a forged shape would read fill values for days."""
        held = _rows_held(ds)
        if held < rows:
            raise self._fail(
                f"{where} declares {rows} rows but the file stores at most {held} of them"
            )

    def _check_series(
        self, ds: Any, where: str, length: int, *, median_step: bool = False
    ) -> float | None:
        """Stream ``ds[:length]``: finite and non-decreasing. Optionally return the median of
        its positive steps (the median of each slice's median, so memory stays bounded)."""
        previous = -math.inf
        medians: list[float] = []
        buffer = np.empty(min(length, _VALIDATE_SLICE), dtype=np.float64)
        for start in range(0, length, _VALIDATE_SLICE):
            stop = min(start + _VALIDATE_SLICE, length)
            values = buffer[: stop - start]
            ds.read_direct(values, np.s_[start:stop], np.s_[0 : stop - start])
            bad = ~np.isfinite(values)
            if bad.any():
                i = int(np.argmax(bad))
                raise self._fail(f"{where}[{start + i}] = {float(values[i])!r}, not finite")
            if values[0] < previous:
                raise self._fail(
                    f"{where} decreases at index {start}: {previous!r} -> {float(values[0])!r}"
                )
            steps = np.diff(values)
            drops = steps < 0
            if drops.any():
                i = int(np.argmax(drops))
                raise self._fail(
                    f"{where} decreases at index {start + i + 1}: "
                    f"{float(values[i])!r} -> {float(values[i + 1])!r}"
                )
            if median_step:
                if start > 0 and values[0] > previous:
                    steps = np.append(steps, values[0] - previous)
                positive = steps[steps > 0]
                if positive.size:
                    medians.append(float(np.median(positive)))
            previous = float(values[-1])
        if not median_step or not medians:
            return None
        return float(np.median(medians))

    # -- reading --------------------------------------------------------------------------

    @property
    def cameras(self) -> tuple[str, ...]:
        """Camera names, sorted."""
        return tuple(self._lines)

    def blocks(
        self,
        block_scans: int = DEFAULT_BLOCK_SCANS,
        *,
        start: int = 0,
        stop: int | None = None,
        max_gap_factor: float = DEFAULT_MAX_GAP_FACTOR,
        smoother: SensorSmoother | None = None,
        lines: bool = True,
    ) -> Iterator[ScanBlock]:
        """Stream scans ``start:stop`` (default: all usable) in blocks of ``block_scans``.

        Each :class:`ScanBlock` holds fresh arrays (``position_m``, ``time_s`` ``[n]``, each
        camera's lines ``[n, W]``: none without ``lines``, for :meth:`camera_lines` to read
        elsewhere) and the vehicle sensors interpolated to the scan times
        (each ``[n]``, ``fault`` as in the module docstring, with a gap meaning more than
        ``max_gap_factor`` median sample intervals), smoothed by ``smoother`` if given (a new
        one per call, made for :attr:`vehicle_interval_s`; it holds the noise estimate once
        the blocks are read). The last block may be shorter.
        """
        if not self._file:
            raise ValueError(f"{self.path}: run file is closed")
        if not _is_int(block_scans) or block_scans < 1:
            raise ValueError(f"block_scans must be a positive integer, got {block_scans!r}")
        scans = self.header.scans
        stop = scans if stop is None else stop
        if not (_is_int(start) and _is_int(stop) and 0 <= start <= stop <= scans):
            raise ValueError(f"need 0 <= start <= stop <= {scans}, got start={start}, stop={stop}")
        if not (math.isfinite(max_gap_factor) and max_gap_factor > 0):
            raise ValueError(f"max_gap_factor must be positive, got {max_gap_factor!r}")
        interval = self.vehicle_interval_s
        max_gap_s = math.inf if interval is None else max_gap_factor * interval
        return self._blocks(int(block_scans), int(start), int(stop), max_gap_s, smoother, lines)

    def _blocks(
        self,
        block_scans: int,
        start: int,
        stop: int,
        max_gap_s: float,
        smoother: SensorSmoother | None,
        lines: bool,
    ) -> Iterator[ScanBlock]:
        vehicle = SensorStream(
            self._read_vehicle, self.vehicle_samples, max_gap_s, SERIES_CHUNK, smoother
        )
        for first in range(start, stop, block_scans):
            last = min(first + block_scans, stop)
            position_m = _read_rows(self._series["position_m"], first, last, np.float64)
            time_s = _read_rows(self._series["time_s"], first, last, np.float64)
            yield ScanBlock(
                first_scan=first,
                position_m=position_m,
                time_s=time_s,
                cameras=self.camera_lines(first, last) if lines else {},
                vehicle=vehicle.at(time_s),
            )

    def image_block(self, first: int, last: int) -> ScanBlock:
        """Scans ``first:last`` with their positions, times and camera lines, the vehicle
        sensors not read (zeros, every scan a fault): for what needs the images alone (image
        evidence), at a cost that does not grow with ``first`` as :meth:`blocks`' does (its
        sensors are read from the run's start)."""
        position_m = _read_rows(self._series["position_m"], first, last, np.float64)
        time_s = _read_rows(self._series["time_s"], first, last, np.float64)
        n = last - first
        unread = VehicleSamples(
            time_s=time_s.copy(),
            left_mm=np.zeros(n),
            right_mm=np.zeros(n),
            lateral_mm=np.zeros(n),
            fault=np.ones(n, dtype=bool),
        )
        return ScanBlock(
            first, position_m, time_s, self._camera_lines(first, last, _few_rows), unread
        )

    def camera_lines(self, first: int, last: int) -> dict[str, CameraLines]:
        """Every camera's lines of scans ``first:last``, fresh arrays ``[last - first, W]``,
        with their ``valid`` flags ``[last - first]`` where the file has them (else None)."""
        return self._camera_lines(first, last, _read_rows)

    def _camera_lines(
        self, first: int, last: int, read: Callable[[Any, int, int, Any], Any]
    ) -> dict[str, CameraLines]:
        """``camera_lines``, the lines read by ``read`` (``_read_rows`` or ``_few_rows``)."""
        if not self._file:
            raise ValueError(f"{self.path}: run file is closed")
        bit_depths = self.header.camera_bit_depth
        offsets = self.header.camera_offset_px
        return {
            name: CameraLines(
                lines=read(ds, first, last, np.dtype(f"u{ds.dtype.itemsize}")),
                bit_depth=bit_depths[name],
                offset_px=offsets.get(name, 0),
                valid=(
                    _read_rows(self._valid[name], first, last, np.bool_)
                    if name in self._valid
                    else None
                ),
            )
            for name, ds in self._lines.items()
        }

    def _read_vehicle(self, first: int, last: int) -> tuple[FloatArray, FloatArray]:
        """Vehicle samples ``first:last``: ``time_s [k]`` and the three sensors ``[3, k]``."""
        t = _read_rows(self._vehicle["time_s"], first, last, np.float64)
        v = np.empty((3, last - first), dtype=np.float64)
        for row, name in enumerate(_VEHICLE_SERIES[1:]):
            v[row] = _read_rows(self._vehicle[name], first, last, np.float64)
        return t, v

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = {True: "complete", False: "interrupted", None: "recording state unknown"}[
            self.complete
        ]
        return f"<RunFile {str(self.path)!r}: {self.header.scans} scans, {state}>"


RunFileReader = RunFile
"""Alias: the reader class is :class:`RunFile`."""


_DAMAGED: Final = (OSError, RuntimeError, KeyError)
"""What h5py raises reading the damaged metadata or chunks of a file it could open."""


def _reason(exc: BaseException) -> str:
    """The first line of an h5py error's message."""
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _rows_held(ds: Any) -> int:
    """The rows of ``ds`` (``[N, ...]``) its file stores, at most: a contiguous dataset's
    allocated bytes over a row's bytes; a chunked one's allocated chunks (whatever their
    compression) times the rows a chunk holds. Rows without storage would read as the fill
    value, which no recorder writes that way."""
    row_bytes = int(ds.dtype.itemsize * math.prod(ds.shape[1:]))
    if ds.chunks is None:
        return int(ds.id.get_storage_size()) // row_bytes if row_bytes else int(ds.shape[0])
    across = int(math.prod(-(-n // c) for n, c in zip(ds.shape[1:], ds.chunks[1:], strict=True)))
    return int(ds.id.get_num_chunks()) // max(across, 1) * int(ds.chunks[0])


def _few_rows(ds: Any, first: int, last: int, dtype: Any) -> Any:
    """``_read_rows``, the rows read straight from the file at their chunks' offsets where
    ``ds`` allows it (chunked by whole rows, unfiltered, of ``dtype``, its chunks allocated):
    for a few rows, which HDF5 would read with the whole chunk (2 MiB for 512 lines of 4096
    pixels, ten times the time)."""
    chunks = ds.chunks
    if (
        chunks is None
        or tuple(chunks[1:]) != tuple(ds.shape[1:])
        or ds.dtype != dtype
        or ds.id.get_create_plist().get_nfilters()
    ):
        return _read_rows(ds, first, last, dtype)
    out = np.empty((last - first, *ds.shape[1:]), dtype=dtype)
    row_bytes = out.itemsize * math.prod(ds.shape[1:])
    handle = ds.file.id.get_vfd_handle()
    for start in range(first - first % chunks[0], last, chunks[0]):
        low, high = max(first, start), min(last, start + chunks[0])
        part = out[low - first : high - first].reshape(-1).view(np.uint8).data
        try:
            offset = ds.id.get_chunk_info_by_coord((start, *[0] * (ds.ndim - 1))).byte_offset
            done = offset is not None and os.preadv(
                handle, [part], offset + (low - start) * row_bytes
            ) == len(part)
        except _DAMAGED:
            done = False
        if not done:  # not stored, or damaged: as HDF5 reads it (or says what is amiss)
            return _read_rows(ds, first, last, dtype)
    return out


def _read_rows(ds: Any, first: int, last: int, dtype: Any) -> Any:
    """Rows ``first:last`` of ``ds`` into a new native-endian array of ``dtype``; a damaged
    chunk is a ``FormatError`` naming the file and the dataset."""
    out = np.empty((last - first, *ds.shape[1:]), dtype=dtype)
    try:
        ds.read_direct(out, np.s_[first:last], np.s_[0 : last - first])
    except _DAMAGED as exc:
        raise FormatError(
            ds.file.filename, f"{ds.name}[{first}:{last}] cannot be read ({_reason(exc)})"
        ) from None
    return out
