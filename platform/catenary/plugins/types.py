"""What plugins register, and what the core hands to the callables they register.

A contribution hook returns registrations (small frozen dataclasses, each with a unique
``name`` per kind: ``Source``, ``VehicleSource``, ``Processor``, ``Reporter``, ``Notifier``,
``Command``, ``ConfigSection``); the core checks their type, refuses a second registration of
a name already taken, and calls the callables they carry inside its error boundary
(``PluginRegistry.boundary``). The payloads are typed too: a reporter gets a
``ReportRequest``, a notifier and the ``catenary_alert_raised`` hook an ``AlertRecord``, and a
processor returns ``WireObservations``.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import click

from catenary.arrays import FloatArray
from catenary.config import Settings
from catenary.domain import RunHeader, ScanBlock, VehicleSamples, WireObservations
from catenary.limits import LimitPolicy
from catenary.wiretype import WireType

if TYPE_CHECKING:
    from catenary.plugins.manager import PluginRegistry
    from catenary.storage.models import Alert

__all__ = [
    "AlertRecord",
    "BlockProcessor",
    "Command",
    "ConfigSection",
    "Notifier",
    "Processor",
    "ReportRequest",
    "Reporter",
    "RunChecker",
    "ScanStream",
    "Source",
    "StagedProcessor",
    "VehicleSource",
    "VehicleStream",
    "WireTypesUser",
]


class ScanStream(Protocol):
    """An open acquisition: a run's header and its scans in blocks.

    Optional attributes, read with ``getattr`` (a stream without them is as if False/None):

    * ``positions_from_encoder: bool``: its blocks carry NaN ``position_m`` (free-running
      cameras): the recorder interpolates each scan's position from the vehicle stream's
      ``encoder_readings`` at its time, and writes the readings to ``/encoder/*``.
    * ``clock_zero_unix_s: float | None``: the host's UNIX time of scan time 0 (a live
      source; known once its first block was yielded): the recorder passes it to the
      vehicle stream's ``align_clock``.

    A block's camera lines may be marked invalid (``CameraLines.valid``): lines the camera
    did not deliver. A block's arrays must stay as they are after the next block is asked
    for: the recorder may hold blocks a while (positions from the encoder).
    """

    header: RunHeader

    def blocks(self, block_scans: int) -> Iterator[ScanBlock]: ...

    def close(self) -> None: ...


class VehicleStream(Protocol):
    """An open vehicle sensor acquisition: timestamped sensor samples, no scans.

    ``vehicle_samples(until_s)`` yields the samples up to ``until_s`` (scan clock) available
    now, in blocks, times non-decreasing across calls; a sample whose fault verdict needs
    later samples may be held back until a later call, or until ``final=True``.

    Optional methods, looked up with ``getattr`` (other vehicle sources need not have them):

    * ``encoder_readings(until_s, *, final=False) -> Iterable[EncoderReadings]``: the wheel
      encoder's good readings up to ``until_s``, as ``vehicle_samples`` gives samples (the
      two may be called in turn over the same times: neither loses the other's data).
    * ``align_clock(clock_zero_unix_s) -> None``: scan time 0 is this host UNIX time; called
      once, before any samples are asked for, when the scan source knows it.
    """

    def vehicle_samples(
        self, until_s: float, *, final: bool = False
    ) -> Iterable[VehicleSamples]: ...

    def close(self) -> None: ...


class BlockProcessor(Protocol):
    """Turns blocks of scans into contact wire observations in the roof frame.

    ``process(block)`` is called for every block in run order and returns the
    ``WireObservations`` decided so far (of this block's scans or earlier ones: a processor
    may hold rows back, for a few metres of track at most, until its tracking decides them);
    ``finish()`` is called once after the last block and returns the rest.
    """

    def process(self, block: ScanBlock) -> WireObservations: ...

    def finish(self) -> WireObservations: ...


@runtime_checkable
class StagedProcessor(Protocol):
    """A ``BlockProcessor`` split into a stateless stage and a stateful rest (optional), so
    that the core may run the stage of several blocks at once in worker processes
    (``catenary process --workers N``).

    ``stage`` is a picklable callable, ``stage(block)``, whose result depends on the block
    alone and is picklable (it is sent to each worker once and called there, for any block, in
    any order); ``process_staged(block, stage(block))`` is then called in run order in the
    core's process and is exactly ``process(block)``. The results must not depend on where
    the stage ran."""

    @property
    def stage(self) -> Callable[[ScanBlock], Any]: ...

    def process_staged(self, block: ScanBlock, staged: Any) -> WireObservations: ...


@runtime_checkable
class RunChecker(Protocol):
    """A ``BlockProcessor`` that checks a run against its calibration (optional): the core
    calls ``check_run(header)`` before the first block; it raises a ``UserError`` in one
    line for a run that does not fit (naming the camera and the values) and may warn."""

    def check_run(self, header: RunHeader) -> None: ...


@runtime_checkable
class WireTypesUser(Protocol):
    """A ``BlockProcessor`` that uses the wire types of the run (optional): the core calls
    ``expect_wire_types(wire_types)`` before the first block with every type the run may
    hold (its ``--wire-type``, else the mast register's types of its track), e.g. to take
    the round wire's radius from their widths rather than assume one."""

    def expect_wire_types(self, wire_types: Sequence[WireType]) -> None: ...


@runtime_checkable
class ImageLocator(Protocol):
    """A ``BlockProcessor`` that tells where roof-frame points lie in each camera's line
    (optional): ``image_columns(x_roof_mm, z_roof_mm)``, arrays ``(k,)`` [mm], returns each
    camera's sensor pixel of them, ``(k,)`` (NaN where a camera cannot see one). Image
    evidence is cut around them; without it, around nothing: the whole line, narrowed."""

    def image_columns(
        self, x_roof_mm: FloatArray, z_roof_mm: FloatArray
    ) -> Mapping[str, FloatArray]: ...


class _KeyAccess:
    """Reading a payload's fields by key, as plugins written for catenary 0.1 did (payloads
    were mappings then): deprecated, and gone in the next release."""

    def __getitem__(self, key: str) -> Any:
        names = {f.name for f in dataclasses.fields(self)}  # type: ignore[arg-type]
        if key not in names:
            raise KeyError(key)
        warnings.warn(
            f"{type(self).__name__}[{key!r}] is deprecated: read the attribute .{key}",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(self, key)

    def get(self, key: str, default: Any = None) -> Any:
        """Deprecated, as ``[key]``."""
        try:
            return self[key]
        except KeyError:
            return default


@dataclass(frozen=True)
class ReportRequest(_KeyAccess):
    """What a reporter's ``write(request, output_path)`` is given.

    ``policy``: the wear-limit policy (``--policy NAME``, else the config's ``[limits]``), None
    without one; ``runs``: the run references given (ids or ``latest``); ``line``, ``track``:
    codes or None; ``options``: the ``--set KEY=VALUE`` pairs. A reporter chooses its
    output's format by the file's suffix and refuses, in one line, what it does not take.
    """

    settings: Settings
    registry: PluginRegistry
    policy: LimitPolicy | None = None
    runs: tuple[str, ...] = ()
    line: str | None = None
    track: str | None = None
    options: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class AlertRecord(_KeyAccess):
    """A committed alert as plugins see it (a notifier's ``send``, the ``catenary_alert_raised``
    hook): its stored fields and its line and track codes, in JSON types (``as_json``).
    ``wire`` is the wire's position in its span (``catenary.positions``), which the JSON
    names ``wire_position``."""

    id: int
    level: str
    kind: str
    status: str
    line: str
    track: str
    wire: int
    mast_from: str | None
    mast_to: str | None
    start_chainage_m: float
    end_chainage_m: float
    value: float
    threshold: float
    rule: str
    condition_key: str
    raised_at: str  # ISO 8601
    details: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, alert: Alert) -> AlertRecord:
        """The record of a stored alert (its track and line loaded)."""
        raised: datetime = alert.raised_at
        return cls(
            id=alert.id,
            level=alert.level,
            kind=alert.kind,
            status=alert.status,
            line=alert.track.line.code,
            track=alert.track.code,
            wire=alert.wire,
            mast_from=alert.mast_from,
            mast_to=alert.mast_to,
            start_chainage_m=alert.start_chainage_m,
            end_chainage_m=alert.end_chainage_m,
            value=alert.value,
            threshold=alert.threshold,
            rule=alert.rule,
            condition_key=alert.condition_key,
            raised_at=raised.isoformat(),
            details=dict(alert.details or {}),
        )

    def as_json(self) -> dict[str, Any]:
        """The record as a JSON object (what the webhook posts as ``alert``)."""
        record = dataclasses.asdict(self)
        record["details"] = dict(self.details)
        return {("wire_position" if k == "wire" else k): v for k, v in record.items()}


@dataclass(frozen=True)
class Source:
    """An acquisition source. ``open(settings)`` starts it and returns a ``ScanStream``."""

    name: str
    description: str
    open: Callable[[Mapping[str, Any]], ScanStream]


@dataclass(frozen=True)
class VehicleSource:
    """A vehicle sensor source (displacement sensors, encoder): ``open(settings)`` starts it
    and returns a ``VehicleStream``; recording writes its samples beside a scan source's."""

    name: str
    description: str
    open: Callable[[Mapping[str, Any]], VehicleStream]


@dataclass(frozen=True)
class Processor:
    """A processing method. ``create(rig_path, settings)`` returns a ``BlockProcessor``."""

    name: str
    description: str
    create: Callable[[Path, Mapping[str, Any]], BlockProcessor]


@dataclass(frozen=True)
class Reporter:
    """A report or export. ``write(request, output_path)`` writes it and returns the path."""

    name: str
    description: str
    write: Callable[[ReportRequest, Path], Path]


@dataclass(frozen=True)
class Notifier:
    """An alert channel. ``send(alert, settings)`` delivers one alert or raises;
    ``check(settings)``, if given, raises ``ValueError`` naming the key for settings ``send``
    would refuse, so the core refuses them when it reads the configuration, not at send time."""

    name: str
    description: str
    send: Callable[[AlertRecord, Mapping[str, Any]], None]
    check: Callable[[Mapping[str, Any]], None] | None = None


@dataclass(frozen=True)
class ConfigSection:
    """A config file section ``[name]`` a plugin reads (``Settings.sections[name]``).

    ``keys``: the keys it may hold, or None for an open table (e.g. subsections named by the
    user); another key is refused, naming the nearest known one. ``check(table)``, if given,
    raises ``ValueError`` naming the key for a wrong value; the core reports it in one line as
    ``FILE: [name] MESSAGE``. Both are applied when a command loads its settings.
    """

    name: str
    keys: frozenset[str] | None = None
    check: Callable[[Mapping[str, Any]], None] | None = None


@dataclass(frozen=True)
class Command:
    """A CLI subcommand added to ``catenary`` under ``name``: a click command whose options
    are declared without importing heavy modules (``catenary --help`` lists it); it takes
    the invocation's ``CommandContext`` with ``@pass_command_context``."""

    name: str
    command: click.Command
