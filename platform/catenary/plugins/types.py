"""What plugins register: small frozen dataclasses, each with a unique ``name`` per kind.

A contribution hook returns these (or a list of them); the core checks their type, refuses a
second registration of a name already taken, and calls the callables they carry inside its own
error boundary (``catenary.plugins``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import click

from catenary.domain import RunHeader, ScanBlock, VehicleSamples
from catenary.wiretype import WireType


class ScanStream(Protocol):
    """An open acquisition: a run's header and its scans in blocks."""

    header: RunHeader

    def blocks(self, block_scans: int) -> Iterator[ScanBlock]: ...

    def close(self) -> None: ...


class VehicleStream(Protocol):
    """An open vehicle sensor acquisition: timestamped sensor samples, no scans.

    ``vehicle_samples(until_s)`` yields the samples up to ``until_s`` (scan clock) available
    now, in blocks, times non-decreasing across calls; a sample whose fault verdict needs
    later samples may be held back until a later call, or until ``final=True``.
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

    def process(self, block: ScanBlock) -> Any: ...

    def finish(self) -> Any: ...


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
    write: Callable[[Mapping[str, Any], Path], Path]


@dataclass(frozen=True)
class Notifier:
    """An alert channel. ``send(alert, settings)`` delivers one alert or raises."""

    name: str
    description: str
    send: Callable[[Mapping[str, Any], Mapping[str, Any]], None]


@dataclass(frozen=True)
class Command:
    """A CLI subcommand added to ``catenary``; ``command.name`` is used unless ``name`` set."""

    name: str
    command: click.Command


KINDS: dict[str, type] = {
    "wire type": WireType,
    "source": Source,
    "vehicle source": VehicleSource,
    "processor": Processor,
    "reporter": Reporter,
    "notifier": Notifier,
    "command": Command,
}
