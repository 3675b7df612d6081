"""The plugin contract: every hook a catenary plugin may implement, in one place.

A plugin is a module or object with functions decorated by ``catenary.hookimpl`` and named
after the specifications below; it is found through the ``catenary.plugins`` entry-point group
(built-ins are registered exactly like third-party plugins). Contribution hooks only return
registration objects (``catenary.plugins.types``); they must not do work or have side effects.
The core calls the callables those objects carry, each inside its own error boundary, so one
broken plugin never takes the platform down. Event hooks are called after the fact; an
exception in one is reported with the plugin's name and does not stop the others.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import pluggy

from catenary.limits import LimitPolicy
from catenary.plugins.types import (
    Command,
    Notifier,
    Processor,
    Reporter,
    Source,
    VehicleSource,
)
from catenary.wiretype import WireType

PROJECT = "catenary"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def catenary_wire_types() -> Iterable[WireType]:
    """Contact wire profiles this plugin provides.

    Called once when the registry first needs wire types. Return ``WireType`` objects, each
    with a name unique across all plugins (``"CTA120"``, ``"AC-100"``).
    """


@hookspec
def catenary_limit_policies() -> Iterable[LimitPolicy]:
    """Wear-limit policies (operators' rules) this plugin ships as presets.

    Return ``LimitPolicy`` objects (``catenary.limits``), each with a unique name; users
    choose one in their config (``[limits] policy = "NAME"``) or bring their own file.
    """


@hookspec
def catenary_sources() -> Iterable[Source]:
    """Acquisition sources: things that yield blocks of scans and vehicle sensor samples.

    Return ``Source`` objects; ``Source.open(settings)`` is called by the core when a run is
    recorded or processed and returns a ``ScanStream``.
    """


@hookspec
def catenary_vehicle_sources() -> Iterable[VehicleSource]:
    """Vehicle sensor sources: the displacement sensors and wheel encoder (e.g. over CAN).

    Return ``VehicleSource`` objects; ``VehicleSource.open(settings)`` returns a
    ``VehicleStream`` that ``catenary record`` writes beside a scan source's blocks.
    """


@hookspec
def catenary_processors() -> Iterable[Processor]:
    """Processing methods: scan blocks and a rig calibration to contact wire observations.

    Return ``Processor`` objects; ``Processor.create(rig_path, settings)`` is called once per
    run and returns a ``BlockProcessor``.
    """


@hookspec
def catenary_reporters() -> Iterable[Reporter]:
    """Reports and exports (run report, maintenance report, linear events, CSV/Parquet).

    Return ``Reporter`` objects; ``Reporter.write(request, output_path)`` is called by
    ``catenary report`` and by scheduled report jobs, and returns the path it wrote.
    """


@hookspec
def catenary_notifiers() -> Iterable[Notifier]:
    """Alert notification channels (e-mail, webhook).

    Return ``Notifier`` objects; ``Notifier.send(alert, settings)`` delivers one alert or
    raises, in which case the core records the failure and retries later.
    """


@hookspec
def catenary_commands() -> Iterable[Command]:
    """Subcommands this plugin adds to the ``catenary`` CLI.

    Return ``Command`` objects wrapping click commands; they are listed by ``catenary --help``
    and run with the invocation's settings (``catenary.cli.app_of(ctx)``).
    """


@hookspec
def catenary_run_stored(run_id: int, database_url: str) -> None:
    """Called after a run and its span measurements are committed to the database."""


@hookspec
def catenary_alert_raised(alert: Mapping[str, Any]) -> None:
    """Called after a new alert is committed; ``alert`` holds its stored fields."""
