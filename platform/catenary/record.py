"""``catenary record``: record a run file from a scan source and, optionally, a vehicle sensor
source, through the one :class:`~catenary.runfile.RunFileWriter`.

How the sources combine
-----------------------
* The **scan source** (``--source NAME``: ``simulator`` now, cameras later; ``recorded``
  replays a run file) is a registered :class:`~catenary.registrations.Source` whose stream
  has a ``header`` and ``blocks(block_scans)`` (:class:`~catenary.registrations.ScanStream`).
  Its header becomes the run's root attributes and cameras; its blocks' positions, times and
  lines are appended as they come.
* The **vehicle sensor source** (``--vehicle-source NAME``, optional: ``can``, live bus or
  log) is a registered ``Source`` whose stream is a :class:`VehicleStream`: it gives no
  scans but timestamped displacement samples on the scan clock, with ``fault`` set where
  they must not be trusted. After each block of scans the recorder writes its samples up to
  the block's last scan time plus :data:`VEHICLE_MARGIN_S` (so every scan has samples on
  both sides), and at the end asks for the rest with ``final=True``. Without a vehicle
  source, the scan source's own ``block.vehicle`` samples are written (at the scan times).
  Which kind a source is, is seen from the stream it opens; naming one in the other's role
  is a one-line error. (A ``VehicleSource`` registration kind of its own would tell the
  roles apart before anything is opened.)
* **Faults.** The run file has no fault column: a sample the source flags is written as NaN,
  which the reader (:mod:`catenary.runfile`) takes as a faulty reading and flags every scan
  between the valid samples either side of it.

Stopping
--------
At the source's end, after ``--max-scans``, or on Ctrl-C. Ctrl-C (SIGINT, or a
``KeyboardInterrupt`` from a source) while waiting on the source stops at once; arriving while
a block is being written, it lets that block finish and stops after it, so the file never
holds half a block. Either way the blocks written so far are kept, the vehicle samples up to
the last scan are written, and the file is closed with its completion marker for the scans it
holds; the command prints one line with the number of scans kept and exits with status 130
(the shell's convention for Ctrl-C). An error (a source failing, bad data from a source, a
full disk) closes the file *without* the marker (it reads as interrupted) and is reported in
one line saying how many scans were kept. A run file with no scan is removed (a source that
gives no scan at all is an error).

Configuration
-------------
A ``[record]`` section may hold ``source``, ``source_options`` (a table), ``vehicle_source``,
``vehicle_options``, ``max_scans`` and ``block_scans``; command-line options win, and a
section's options apply only to the source it names. ``KEY=VALUE`` options are read as TOML
values (``20``, ``1.5``, ``true``, ``{a = 1}``), else as plain strings (``can0``,
``/data/run.blf``); quote a string that looks like a number: ``track='"1"'``.
"""

from __future__ import annotations

import signal
import sys
import threading
import tomllib
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any, Final, Self

import click
import numpy as np

from catenary.domain import RunHeader, ScanBlock, VehicleSamples
from catenary.errors import UserError
from catenary.plugins import PluginRegistry
from catenary.registrations import ScanStream, Source, VehicleSource, VehicleStream
from catenary.runfile import DEFAULT_BLOCK_SCANS, RunFileWriter

__all__ = [
    "INTERRUPTED_EXIT_CODE",
    "VEHICLE_MARGIN_S",
    "Recording",
    "VehicleStream",
    "parse_options",
    "record",
    "record_run",
]

VEHICLE_MARGIN_S: Final = 0.5
"""Vehicle samples are written up to this long after the last scan written [s]."""
INTERRUPTED_EXIT_CODE: Final = 130
RECORD_KEYS: Final = {
    "source",
    "source_options",
    "vehicle_source",
    "vehicle_options",
    "max_scans",
    "block_scans",
}


@dataclass(frozen=True)
class Recording:
    """What :func:`record_run` wrote."""

    path: Path
    scans: int
    vehicle_samples: int
    flagged_vehicle_samples: int  # samples the source flagged (written as NaN)
    interrupted: bool


class _VehicleWriter:
    """Appends vehicle samples, the flagged ones (and missing readings) as NaN."""

    def __init__(self, writer: RunFileWriter, source: str) -> None:
        self._writer = writer
        self._source = source
        self.samples = 0
        self.flagged = 0

    def push(self, samples: VehicleSamples) -> None:
        time_s = np.asarray(samples.time_s, dtype=np.float64)
        series = [
            np.asarray(samples.left_mm, dtype=np.float64),
            np.asarray(samples.right_mm, dtype=np.float64),
            np.asarray(samples.lateral_mm, dtype=np.float64),
        ]
        if time_s.ndim != 1 or any(v.shape != time_s.shape for v in series):
            raise UserError(f"{self._source}: vehicle samples of mismatched lengths")
        if time_s.shape[0] == 0:
            return
        values = np.stack(series)
        fault = np.asarray(samples.fault, dtype=bool)
        if fault.shape != time_s.shape:
            fault = np.zeros(time_s.shape, dtype=bool)
        fault = fault | ~np.isfinite(values).all(axis=0)  # a missing reading is a fault too
        self.samples += int(time_s.shape[0])
        self.flagged += int(np.count_nonzero(fault))
        values = np.where(fault, np.nan, values)
        try:
            self._writer.append_vehicle(time_s, values[0], values[1], values[2])
        except ValueError as exc:
            raise UserError(f"{self._source}: invalid vehicle samples: {exc}") from None


class _InterruptGuard:
    """Ctrl-C during a recording.

    Installed as the SIGINT handler (in the main thread only). The first Ctrl-C sets
    ``requested``; it also raises ``KeyboardInterrupt`` unless a write is under way
    (:meth:`deferred`), in which case the recording stops after the write. Later ones only
    set ``requested``, so the file is always closed properly.
    """

    def __init__(self) -> None:
        self.requested = False
        self._deferring = 0
        self._previous: Any = None
        self._installed = False

    def __enter__(self) -> Self:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._installed:
            previous = self._previous if self._previous is not None else signal.default_int_handler
            signal.signal(signal.SIGINT, previous)
            self._installed = False

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        first = not self.requested
        self.requested = True
        if first and not self._deferring:
            raise KeyboardInterrupt

    @contextmanager
    def deferred(self) -> Iterator[None]:
        """Ctrl-C inside only sets ``requested``."""
        self._deferring += 1
        try:
            yield
        finally:
            self._deferring -= 1


@contextmanager
def _source_errors(name: str) -> Iterator[None]:
    """A source's own failure (not a user error) as a one-line ``UserError`` naming it."""
    try:
        yield
    except (UserError, KeyboardInterrupt):
        raise
    except Exception as exc:
        text = " ".join(str(exc).split())
        detail = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
        raise UserError(f"{name} failed: {detail}") from None


def _append_scans(writer: RunFileWriter, block: ScanBlock, n: int, source: str) -> None:
    lines = {name: camera.lines[:n] for name, camera in block.cameras.items()}
    try:
        writer.append(block.position_m[:n], block.time_s[:n], lines)
    except ValueError as exc:
        raise UserError(f"{source}: invalid block of scans: {exc}") from None


def _slice_vehicle(samples: VehicleSamples, n: int) -> VehicleSamples:
    return VehicleSamples(
        time_s=samples.time_s[:n],
        left_mm=samples.left_mm[:n],
        right_mm=samples.right_mm[:n],
        lateral_mm=samples.lateral_mm[:n],
        fault=samples.fault[:n],
    )


def record_run(
    path: str | Path,
    scans: ScanStream,
    *,
    vehicle: VehicleStream | None = None,
    max_scans: int | None = None,
    block_scans: int = DEFAULT_BLOCK_SCANS,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
    scan_source: str = "scan source",
    vehicle_source: str = "vehicle source",
) -> Recording:
    """Record ``scans`` (and ``vehicle``'s samples) into the run file ``path``.

    Parameters
    ----------
    path : path-like
        The run file to create (``UserError`` if it exists, unless ``overwrite``).
    scans : ScanStream
        The open scan source: its ``header`` and ``blocks(block_scans)``.
    vehicle : VehicleStream, optional
        The open vehicle sensor source; none: the scan blocks' own vehicle samples.
    max_scans : int, optional
        Stop after this many scans.
    block_scans : int
        Scans asked of the source per block.
    progress : callable, optional
        Called with the number of scans written after each block.
    scan_source, vehicle_source : str
        Names for messages (``"source 'simulator'"``).

    Returns the :class:`Recording`; ``interrupted`` is true when Ctrl-C stopped it (the file
    is complete for the scans it holds). Errors: module docstring. The streams are not closed.
    """
    path = Path(path)
    if max_scans is not None and max_scans < 1:
        raise ValueError(f"max_scans must be positive, got {max_scans}")
    if path.exists() and not overwrite:
        raise UserError(f"{path}: already exists (not overwritten)")
    if not path.parent.is_dir():
        raise UserError(f"{path.parent}: no such directory")
    header: RunHeader = scans.header
    cameras = {
        name: (pixels, header.camera_bit_depth[name])
        for name, pixels in header.camera_pixels.items()
    }
    with _InterruptGuard() as guard:
        with guard.deferred():
            try:
                writer = RunFileWriter(
                    path,
                    line=header.line,
                    track=header.track,
                    vehicle=header.vehicle,
                    direction=header.direction,
                    start_chainage_m=header.start_chainage_m,
                    started_at=header.started_at,
                    scan_rate_hz=header.scan_rate_hz,
                    cameras=cameras,
                    overwrite=overwrite,
                )
            except ValueError as exc:
                raise UserError(f"{scan_source}: invalid run header: {exc}") from None
        samples = _VehicleWriter(writer, vehicle_source if vehicle is not None else scan_source)
        try:
            _stream_blocks(
                writer,
                samples,
                guard,
                scans,
                vehicle,
                max_scans,
                block_scans,
                progress,
                scan_source,
                vehicle_source,
            )
        except BaseException as exc:
            kept = writer.scans
            writer.abort()
            if kept == 0:
                path.unlink(missing_ok=True)
            if isinstance(exc, UserError | OSError) and kept:
                reason = str(exc) if isinstance(exc, UserError) else f"{exc.strerror or exc}"
                raise UserError(
                    f"{reason}; kept {kept} scans in {path} (no completion marker: reads as "
                    "interrupted)"
                ) from None
            raise
    if writer.scans == 0:  # nothing to keep: leave no empty run behind
        path.unlink(missing_ok=True)
        if not guard.requested:
            raise UserError(f"{scan_source} gave no scans: nothing recorded")
    return Recording(path, writer.scans, samples.samples, samples.flagged, guard.requested)


def _stream_blocks(
    writer: RunFileWriter,
    samples: _VehicleWriter,
    guard: _InterruptGuard,
    scans: ScanStream,
    vehicle: VehicleStream | None,
    max_scans: int | None,
    block_scans: int,
    progress: Callable[[int], None] | None,
    scan_source: str,
    vehicle_source: str,
) -> None:
    """The recording loop of :func:`record_run`; closes the writer with its marker at the end
    or on Ctrl-C (``guard.requested``), raises on errors."""
    last_time_s: float | None = None
    blocks: Iterator[ScanBlock] | None = None
    try:
        with _source_errors(scan_source):
            blocks = iter(scans.blocks(block_scans))
        while not guard.requested and (max_scans is None or writer.scans < max_scans):
            with _source_errors(scan_source):
                block = next(blocks, None)  # Ctrl-C raises here while the source waits
            if block is None:
                break
            n = block.scans if max_scans is None else min(block.scans, max_scans - writer.scans)
            if n == 0:
                continue
            with guard.deferred():  # Ctrl-C here only sets guard.requested
                _append_scans(writer, block, n, scan_source)
                last_time_s = float(block.time_s[n - 1])
                if vehicle is None:
                    samples.push(_slice_vehicle(block.vehicle, n))
                else:
                    with _source_errors(vehicle_source):
                        for part in vehicle.vehicle_samples(last_time_s + VEHICLE_MARGIN_S):
                            samples.push(part)
            if progress is not None:
                progress(n)
    except KeyboardInterrupt:
        guard.requested = True
    with guard.deferred():
        close = getattr(blocks, "close", None)
        if callable(close):
            with _source_errors(scan_source):
                close()
        if vehicle is not None and last_time_s is not None:
            with _source_errors(vehicle_source):
                for part in vehicle.vehicle_samples(last_time_s + VEHICLE_MARGIN_S, final=True):
                    samples.push(part)
        writer.close()


# --------------------------------------------------------------------------------------------
# The command


def parse_options(pairs: Iterable[str], option: str) -> dict[str, Any]:
    """``KEY=VALUE`` strings to a settings mapping (values as TOML, else plain strings)."""
    settings: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        key = key.strip()
        if not sep or not key:
            raise click.BadParameter(f"expected KEY=VALUE, got {pair!r}", param_hint=option)
        try:
            value: Any = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text
        settings[key] = value
    return settings


def _record_section(section: Any, config_path: Path | None) -> dict[str, Any]:
    where = f"{config_path}: " if config_path is not None else ""
    if section is None:
        return {}
    if not isinstance(section, dict):
        raise UserError(f"{where}[record] must be a table")
    unknown = sorted(set(section) - RECORD_KEYS)
    if unknown:
        raise UserError(
            f"{where}unknown key record.{unknown[0]} (known: {', '.join(sorted(RECORD_KEYS))})"
        )
    for key in ("source", "vehicle_source"):
        if key in section and not isinstance(section[key], str):
            raise UserError(f"{where}record.{key} must be a source name")
    for key in ("source_options", "vehicle_options"):
        if key in section and not isinstance(section[key], dict):
            raise UserError(f"{where}record.{key} must be a table")
    for key in ("max_scans", "block_scans"):
        value = section.get(key)
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, int) or value < 1
        ):
            raise UserError(f"{where}record.{key} must be a positive integer")
    return dict(section)


def _settings_for(
    name: str, config: Mapping[str, Any], name_key: str, options_key: str, cli: dict[str, Any]
) -> dict[str, Any]:
    """The config's options for ``name`` (if it is the configured source), then the CLI's."""
    settings: dict[str, Any] = {}
    if config.get(name_key) == name:
        settings.update(config.get(options_key, {}))
    settings.update(cli)
    return settings


def _open_source(
    registry: PluginRegistry, name: str, settings: Mapping[str, Any], kind: str
) -> tuple[Any, str]:
    """Open the scan source (``kind`` "source") or vehicle source ("vehicle source") ``name``."""
    sources: Mapping[str, Source | VehicleSource] = (
        registry.sources() if kind == "source" else registry.vehicle_sources()
    )
    source = sources.get(name)
    if source is None:
        other = registry.vehicle_sources() if kind == "source" else registry.sources()
        hint = ""
        if name in other:
            other_kind, option = (
                ("vehicle source", "--vehicle-source")
                if kind == "source"
                else ("source", "--source")
            )
            hint = f"; {name!r} is a {other_kind}: use {option}"
        known = ", ".join(sorted(sources)) or "none"
        raise UserError(f"unknown {kind} {name!r} (known: {known}){hint}")
    label = f"{kind} {name!r} (plugin {registry.owner(kind, name)})"
    with _source_errors(label):
        stream = source.open(settings)
    return stream, f"{kind} {name!r}"


def _close(stream: object) -> None:
    close = getattr(stream, "close", None)
    if callable(close):
        close()


@click.command("record")
@click.argument("out", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--source",
    "source_name",
    metavar="NAME",
    help="Scan source (e.g. simulator; default: [record] source).",
)
@click.option(
    "--source-option",
    "source_options",
    multiple=True,
    metavar="KEY=VALUE",
    help="A setting of the scan source (repeatable), e.g. length_m=20.",
)
@click.option(
    "--vehicle-source",
    "vehicle_name",
    metavar="NAME",
    help="Vehicle sensor source (e.g. can; default: [record] vehicle_source, else the scan "
    "source's own sensor samples).",
)
@click.option(
    "--vehicle-option",
    "vehicle_options",
    multiple=True,
    metavar="KEY=VALUE",
    help="A setting of the vehicle sensor source (repeatable), e.g. log=run.blf or "
    "interface=socketcan.",
)
@click.option(
    "--no-vehicle-source",
    is_flag=True,
    help="Ignore [record] vehicle_source: use the scan source's sensor samples.",
)
@click.option(
    "--max-scans",
    type=click.IntRange(min=1),
    help="Stop after this many scans (default: [record] max_scans, else the source's end).",
)
@click.option(
    "--block-scans",
    type=click.IntRange(min=1),
    help=f"Scans per block (default: [record] block_scans, else {DEFAULT_BLOCK_SCANS}).",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing OUT.")
@click.pass_context
def record(
    ctx: click.Context,
    out: Path,
    source_name: str | None,
    source_options: tuple[str, ...],
    vehicle_name: str | None,
    vehicle_options: tuple[str, ...],
    no_vehicle_source: bool,
    max_scans: int | None,
    block_scans: int | None,
    overwrite: bool,
) -> None:
    """Record a run file OUT.h5 from a scan source and, optionally, a vehicle sensor source.

    Ctrl-C stops cleanly: the scans recorded so far are kept in a complete run file.
    """
    from catenary.cli import app_of  # the CLI module imports this one

    app = app_of(ctx)
    config = _record_section(app.settings.sections.get("record"), app.settings.config_path)
    scan_cli = parse_options(source_options, "--source-option")
    vehicle_cli = parse_options(vehicle_options, "--vehicle-option")
    source_name = source_name or config.get("source")
    if not source_name:
        raise click.UsageError("no scan source: give --source NAME or [record] source")
    if no_vehicle_source:
        if vehicle_name or vehicle_cli:
            raise click.UsageError("--no-vehicle-source with --vehicle-source/--vehicle-option")
    else:
        vehicle_name = vehicle_name or config.get("vehicle_source")
    if vehicle_cli and not vehicle_name:
        raise click.UsageError("--vehicle-option needs --vehicle-source NAME")
    max_scans = max_scans if max_scans is not None else config.get("max_scans")
    block_scans = block_scans or config.get("block_scans") or DEFAULT_BLOCK_SCANS
    registry = app.registry

    with ExitStack() as stack:
        scan_settings = _settings_for(source_name, config, "source", "source_options", scan_cli)
        scan_stream, scan_label = _open_source(registry, source_name, scan_settings, "source")
        stack.callback(_close, scan_stream)
        vehicle_stream: VehicleStream | None = None
        vehicle_label = "vehicle source"
        if vehicle_name:
            settings = _settings_for(
                vehicle_name, config, "vehicle_source", "vehicle_options", vehicle_cli
            )
            vehicle_stream, vehicle_label = _open_source(
                registry, vehicle_name, settings, "vehicle source"
            )
            stack.callback(_close, vehicle_stream)

        header = scan_stream.header
        total = header.scans if header.scans > 0 else None
        if max_scans is not None:
            total = max_scans if total is None else min(total, max_scans)
        progress: Callable[[int], None] | None = None
        if total:
            bar = stack.enter_context(
                click.progressbar(
                    length=total, label=f"recording {out.name}", show_pos=True, file=sys.stderr
                )
            )
            progress = bar.update
        result = record_run(
            out,
            scan_stream,
            vehicle=vehicle_stream,
            max_scans=max_scans,
            block_scans=block_scans,
            overwrite=overwrite,
            progress=progress,
            scan_source=scan_label,
            vehicle_source=vehicle_label,
        )
    summary = getattr(vehicle_stream, "summary", None)
    if callable(summary):
        click.echo(str(summary()))
    if result.interrupted:
        click.echo(
            f"interrupted: kept {result.scans} scans in {result.path} "
            "(complete up to the last block)"
            if result.scans
            else "interrupted before the first block: nothing recorded",
            err=True,
        )
        ctx.exit(INTERRUPTED_EXIT_CODE)
    click.echo(
        f"recorded {result.path}: {result.scans} scans, {result.vehicle_samples} vehicle "
        f"samples ({result.flagged_vehicle_samples} flagged)"
    )
