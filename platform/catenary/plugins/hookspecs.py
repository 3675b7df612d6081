"""The plugin contract: every hook a catenary plugin may implement, in one place.

A plugin is a module or object with functions decorated by ``catenary.plugins.hookimpl`` and
named after the specifications below; it is found through the ``catenary.plugins`` entry-point
group (built-ins are registered exactly like third-party plugins)::

    # pyproject.toml of the plugin's distribution
    [project.entry-points."catenary.plugins"]
    my-wires = "my_wires"

Contribution hooks only return registration objects (``catenary.plugins.types``); they must
not do work or have side effects, and they import heavy modules inside the callables they
register, not at the top of the plugin (``catenary --help`` loads every plugin). The core
calls those callables inside its error boundary (``PluginRegistry.boundary``), so one broken
plugin never takes the platform down. Event hooks are called after the fact; an exception in
one is reported with the plugin's name and does not stop the others.
"""

from __future__ import annotations

from collections.abc import Iterable

import pluggy

from catenary.limits import LimitPolicy
from catenary.plugins.types import (
    AlertRecord,
    Command,
    ConfigSection,
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
    with a name unique across all plugins (``"CTA120"``, ``"AC-100"``)::

        @hookimpl
        def catenary_wire_types():
            return [WireType(name="XW-95", standard="ACME XW", height_mm=11.2,
                             width_mm=11.2, area_mm2=95.0, nominal_area_mm2=95.0)]
    """


@hookspec
def catenary_limit_policies() -> Iterable[LimitPolicy]:
    """Wear-limit policies (operators' rules) this plugin ships as presets.

    Return ``LimitPolicy`` objects (``catenary.limits``), each with a unique name; users
    choose one in their config (``[limits] policy = "NAME"``) or bring their own file::

        @hookimpl
        def catenary_limit_policies():
            return load_policies(Path(__file__).with_name("limits.toml")).values()
    """


@hookspec
def catenary_sources() -> Iterable[Source]:
    """Acquisition sources: things that yield blocks of scans and vehicle sensor samples.

    Return ``Source`` objects; ``Source.open(settings)`` is called by the core when a run is
    recorded and returns a ``ScanStream``::

        @hookimpl
        def catenary_sources():
            def open_camera(settings):
                from my_camera.stream import CameraStream  # heavy: on use only
                return CameraStream(settings)
            return [Source("my-camera", "ACME line-scan cameras", open_camera)]
    """


@hookspec
def catenary_vehicle_sources() -> Iterable[VehicleSource]:
    """Vehicle sensor sources: the displacement sensors and wheel encoder (e.g. over CAN).

    Return ``VehicleSource`` objects; ``VehicleSource.open(settings)`` returns a
    ``VehicleStream`` that ``catenary record`` writes beside a scan source's blocks::

        @hookimpl
        def catenary_vehicle_sources():
            return [VehicleSource("my-bus", "ACME sensor bus", open_bus)]
    """


@hookspec
def catenary_processors() -> Iterable[Processor]:
    """Processing methods: scan blocks and a rig calibration to contact wire observations.

    Return ``Processor`` objects; ``Processor.create(rig_path, settings)`` is called once per
    run and returns a ``BlockProcessor``, whose ``process(block)`` and ``finish()`` return
    ``WireObservations`` in the roof frame (a row the method cannot decide is the contact
    wire carries ``selection_uncertain``: stored, but left out of span figures and alerts)::

        @hookimpl
        def catenary_processors():
            return [Processor("my-method", "ACME's wire finder", create_my_processor)]
    """


@hookspec
def catenary_reporters() -> Iterable[Reporter]:
    """Reports and exports (run report, maintenance report, linear events, CSV/Parquet).

    Return ``Reporter`` objects; ``Reporter.write(request, output_path)`` is called with a
    ``ReportRequest`` by ``catenary report`` and by scheduled report jobs, and returns the
    path it wrote::

        @hookimpl
        def catenary_reporters():
            def write(request: ReportRequest, output: Path) -> Path:
                output.write_text(f"runs {', '.join(request.runs)}\\n")
                return output
            return [Reporter("runs-list", "the runs asked for, one line", write)]
    """


@hookspec
def catenary_notifiers() -> Iterable[Notifier]:
    """Alert notification channels (e-mail, webhook).

    Return ``Notifier`` objects; ``Notifier.send(alert, settings)`` delivers one
    ``AlertRecord`` with the channel's settings, or raises, in which case the core records the
    failure and retries later::

        @hookimpl
        def catenary_notifiers():
            def send(alert: AlertRecord, settings) -> None:
                pager.page(settings["number"], f"{alert.level}: line {alert.line}")
            return [Notifier("pager", "ACME pager", send)]
    """


@hookspec
def catenary_commands() -> Iterable[Command]:
    """Subcommands this plugin adds to the ``catenary`` CLI.

    Return ``Command`` objects wrapping click commands; they are listed by ``catenary --help``
    and take the invocation's ``CommandContext`` (settings, registry, database)::

        @click.command("hello")
        @pass_command_context
        def hello(context: CommandContext) -> None:
            click.echo(f"{len(context.registry.wire_types())} wire types")

        @hookimpl
        def catenary_commands():
            return [Command("hello", hello)]
    """


@hookspec
def catenary_config_sections() -> Iterable[ConfigSection]:
    """Config file sections this plugin reads (``settings.sections[name]``).

    A section of the config file that neither the core nor a plugin declares is an error, as
    is a key a section does not list; ``check`` refuses wrong values when settings are loaded.
    Return ``ConfigSection`` objects, each with a name unique across the core and all plugins::

        @hookimpl
        def catenary_config_sections():
            def check(table):
                if not isinstance(table.get("exposure_us", 100), int):
                    raise ValueError("exposure_us must be a whole number of microseconds")
            return [ConfigSection("camera", frozenset({"exposure_us", "gain_db"}), check)]
    """


@hookspec
def catenary_run_stored(run_id: int, database_url: str) -> None:
    """Called after a run and its span measurements are committed to the database (the URL may
    hold a password: show it only through ``catenary.storage.database.mask_url``)::

    @hookimpl
    def catenary_run_stored(run_id, database_url):
        log.info("run %d stored in %s", run_id, mask_url(database_url))
    """


@hookspec
def catenary_alert_raised(alert: AlertRecord) -> None:
    """Called after a new alert is committed, with its ``AlertRecord``::

    @hookimpl
    def catenary_alert_raised(alert):
        log.info("alert %d: %s on line %s", alert.id, alert.level, alert.line)
    """
