"""A migrated database, settings from a config file, and a plugin with a fake reporter and a
fake notifier for the scheduler's tests."""

from __future__ import annotations

import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest

from catenary.plugins import AlertRecord, PluginRegistry, ReportRequest, hookimpl
from catenary.plugins.types import Notifier, Reporter


class Fakes:
    """Reporter ``fake`` (records its calls; waits for ``hold`` if set, raises ``error`` if
    set) and notifier ``fake`` (records its alerts; raises ``send_error`` if set)."""

    def __init__(self) -> None:
        self.reports: list[tuple[ReportRequest, Path]] = []
        self.sent: list[AlertRecord] = []
        self.error: Exception | None = None
        self.send_error: Exception | None = None
        self.hold: threading.Event | None = None

    def write(self, request: ReportRequest, path: Path) -> Path:
        if self.hold is not None:
            self.hold.wait(30)
        if self.error is not None:
            raise self.error
        self.reports.append((request, path))
        return path

    def send(self, alert: AlertRecord, settings: Mapping[str, Any]) -> None:
        if self.send_error is not None:
            raise self.send_error
        self.sent.append(alert)

    @hookimpl
    def catenary_reporters(self) -> list[Reporter]:
        return [Reporter("fake", "records", self.write)]

    @hookimpl
    def catenary_notifiers(self) -> list[Notifier]:
        return [Notifier("fake", "records", self.send)]


@pytest.fixture
def fakes() -> Iterator[Fakes]:
    fakes = Fakes()
    yield fakes
    if fakes.hold is not None:
        fakes.hold.set()


@pytest.fixture
def registry(fakes: Fakes) -> PluginRegistry:
    return PluginRegistry(autoload=False, plugins=[("fakes", fakes)])
