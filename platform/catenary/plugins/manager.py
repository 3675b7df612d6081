"""The plugin registry: loads plugins, collects their registrations, reports their failures.

It is the only caller of the hooks. Each entry point is loaded on its own and each hook
implementation is called on its own, so a plugin that fails to import, raises inside a hook,
returns the wrong type or registers a name another plugin already took is reported by name
(``PluginRegistry.errors``) and the platform keeps working with the others. Every call into
the callables plugins register runs inside one error boundary (``plugin_errors``, or
``PluginRegistry.boundary``), which names the plugin and the kind in one line.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, TypeVar

import click
import pluggy

from catenary.config import CORE_SECTIONS, KNOWN_KEYS, Settings, did_you_mean
from catenary.errors import UserError, one_line
from catenary.limits import LimitPolicy
from catenary.plugins import hookspecs
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
from catenary.wiretype import ProfileRangeError, WireType

ENTRY_POINT_GROUP = "catenary.plugins"
DISABLE_AUTOLOAD_ENV = "CATENARY_DISABLE_PLUGIN_AUTOLOAD"
BUILTIN_DISTRIBUTION = "catenary"

T = TypeVar("T")


@dataclass(frozen=True)
class PluginError:
    """A plugin's failure: which plugin, at what stage, and what went wrong (one line)."""

    plugin: str
    stage: str
    message: str

    def __str__(self) -> str:
        return f"plugin {self.plugin!r} ({self.stage}): {self.message}"


class PluginFailure(UserError):
    """Plugin code failed, not through the user's input: one line naming the plugin and the
    kind (``what``), then the plugin's own error (``detail``, ``Type: message``)."""

    def __init__(self, what: str, detail: str) -> None:
        super().__init__(f"{what} failed: {detail}")
        self.what = what
        self.detail = detail


_PASSED_THROUGH: tuple[type[BaseException], ...] = (
    UserError,
    ProfileRangeError,
    click.ClickException,
    click.exceptions.Exit,
    click.exceptions.Abort,
)
"""What plugin code may raise as it is: errors the user can act on, and click's own."""


@contextmanager
def plugin_errors(what: str) -> Iterator[None]:
    """The error boundary around plugin code for ``what`` (``"processor 'x' of plugin 'y'"``):
    an exception the user can act on (a ``UserError``, a file error naming its file, click's
    own) passes as it is; any other becomes a ``PluginFailure`` naming ``what``."""
    try:
        yield
    except _PASSED_THROUGH:
        raise
    except OSError as exc:
        if exc.filename:
            raise
        raise PluginFailure(what, one_line(exc)) from exc
    except Exception as exc:
        raise PluginFailure(what, one_line(exc)) from exc


class PluginRegistry:
    """Loaded plugins and what they register.

    ``autoload`` loads every ``catenary.plugins`` entry point (with the environment variable
    ``CATENARY_DISABLE_PLUGIN_AUTOLOAD`` set, only the built-ins shipped in the ``catenary``
    distribution); ``plugins`` adds ``(name, plugin)`` pairs directly (tests, embedding);
    ``disabled`` names plugins not to load.
    """

    def __init__(
        self,
        *,
        autoload: bool = True,
        plugins: Iterable[tuple[str, object]] = (),
        disabled: Iterable[str] = (),
    ) -> None:
        self._pm = pluggy.PluginManager(hookspecs.PROJECT)
        self._pm.add_hookspecs(hookspecs)
        self._disabled = set(disabled)
        self.errors: list[PluginError] = []
        self._cache: dict[str, dict[str, Any]] = {}
        self._owner: dict[tuple[str, str], str] = {}
        if autoload:
            self._load_entry_points()
        for name, plugin in plugins:
            self._register(name, plugin)
        self._check_pending()

    def _load_entry_points(self) -> None:
        builtins_only = os.environ.get(DISABLE_AUTOLOAD_ENV, "") not in ("", "0")
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            dist = ep.dist.name if ep.dist is not None else ""
            if builtins_only and dist != BUILTIN_DISTRIBUTION:
                continue
            if ep.name in self._disabled or self._pm.has_plugin(ep.name):
                continue
            try:
                plugin = ep.load()
            except Exception as exc:
                self.errors.append(PluginError(ep.name, "load", one_line(exc)))
                continue
            self._register(ep.name, plugin)

    def _register(self, name: str, plugin: object) -> None:
        if name in self._disabled:
            return
        if self._pm.has_plugin(name):
            self.errors.append(PluginError(name, "load", "a plugin of this name is loaded"))
            return
        try:
            self._pm.register(plugin, name=name)
        except Exception as exc:
            self.errors.append(PluginError(name, "load", one_line(exc)))

    def _check_pending(self) -> None:
        """Unregister plugins whose hook implementations match no specification."""
        while True:
            try:
                self._pm.check_pending()
                return
            except pluggy.PluginValidationError as exc:
                name = self._pm.get_name(exc.plugin) or repr(exc.plugin)
                self.errors.append(PluginError(name, "load", one_line(exc)))
                self._pm.unregister(exc.plugin)

    @property
    def plugin_names(self) -> list[str]:
        """Names of the plugins loaded, in load order."""
        return [name for name, _ in self._pm.list_name_plugin()]

    def _collect(self, hook: str, kind: str, cls: type[T]) -> dict[str, T]:
        if hook in self._cache:
            return self._cache[hook]
        found: dict[str, T] = {}
        caller = getattr(self._pm.hook, hook)
        for impl in caller.get_hookimpls():  # registration (load) order; pluggy calls LIFO
            plugin = impl.plugin_name
            try:
                result = impl.function()
                items = [] if result is None else list(result)
            except Exception as exc:
                self.errors.append(PluginError(plugin, hook, one_line(exc)))
                continue
            for item in items:
                if not isinstance(item, cls):
                    message = f"returned {type(item).__name__}, not a {cls.__name__}"
                    self.errors.append(PluginError(plugin, hook, message))
                    continue
                item_name = getattr(item, "name", "")
                if item_name in found:
                    first = self._owner[(kind, item_name)]
                    message = f"{kind} {item_name!r} is already registered by plugin {first!r}"
                    self.errors.append(PluginError(plugin, hook, message))
                    continue
                found[item_name] = item
                self._owner[(kind, item_name)] = plugin
        self._cache[hook] = found
        return found

    def owner(self, kind: str, name: str) -> str:
        """The plugin that registered ``name`` of ``kind`` (e.g. ``"wire type"``)."""
        return self._owner[(kind, name)]

    def describe(self, kind: str, name: str) -> str:
        """``"reporter 'run' of plugin 'reports'"``: what an error names."""
        return f"{kind} {name!r} of plugin {self.owner(kind, name)!r}"

    def boundary(self, kind: str, name: str) -> contextlib.AbstractContextManager[None]:
        """The error boundary (``plugin_errors``) around a call into what plugin registered as
        ``name`` of ``kind``::

            with registry.boundary("reporter", name):
                reporter.write(request, output)
        """
        return plugin_errors(self.describe(kind, name))

    def wire_types(self) -> dict[str, WireType]:
        return self._collect("catenary_wire_types", "wire type", WireType)

    def limit_policies(self) -> dict[str, LimitPolicy]:
        return self._collect("catenary_limit_policies", "limit policy", LimitPolicy)

    def sources(self) -> dict[str, Source]:
        return self._collect("catenary_sources", "source", Source)

    def vehicle_sources(self) -> dict[str, VehicleSource]:
        return self._collect("catenary_vehicle_sources", "vehicle source", VehicleSource)

    def processors(self) -> dict[str, Processor]:
        return self._collect("catenary_processors", "processor", Processor)

    def reporters(self) -> dict[str, Reporter]:
        return self._collect("catenary_reporters", "reporter", Reporter)

    def notifiers(self) -> dict[str, Notifier]:
        return self._collect("catenary_notifiers", "notifier", Notifier)

    def commands(self) -> dict[str, Command]:
        return self._collect("catenary_commands", "command", Command)

    def config_sections(self) -> dict[str, ConfigSection]:
        """The sections plugins declare; one the core reads itself is refused (an error)."""
        found = self._collect("catenary_config_sections", "config section", ConfigSection)
        for name in sorted(set(found) & (CORE_SECTIONS | set(KNOWN_KEYS))):
            message = f"config section [{name}] is the core's"
            self.errors.append(PluginError(self.owner("config section", name), "load", message))
            del found[name]
        return found

    def check_settings(self, settings: Settings) -> None:
        """Refuse, in one ``UserError`` naming the config file, a section of ``settings`` that
        neither the core nor a plugin reads, a key its plugin does not list, or a value its
        plugin's ``check`` refuses."""
        declared = self.config_sections()
        where = settings.config_path or "config"
        known = CORE_SECTIONS | set(KNOWN_KEYS) | set(declared)
        for name, table in settings.sections.items():
            if name in CORE_SECTIONS:
                continue
            section = declared.get(name)
            if section is None:
                hint = did_you_mean(name, known, brackets=True)
                what = f"section [{name}]" if isinstance(table, dict) else f"top-level key {name!r}"
                raise UserError(f"{where}: unknown {what}{hint}")
            if not isinstance(table, dict):
                raise UserError(f"{where}: [{name}] must be a table")
            if section.keys is not None:
                unknown = sorted(set(table) - section.keys)
                if unknown:
                    hint = did_you_mean(unknown[0], section.keys)
                    raise UserError(f"{where}: unknown key {name}.{unknown[0]}{hint}")
            if section.check is not None:
                with self.boundary("config section", name):
                    try:
                        section.check(table)
                    except ValueError as exc:
                        message = " ".join(str(exc).split())
                        raise UserError(f"{where}: [{name}] {message}") from None

    def registrations(self) -> dict[str, dict[str, list[str]]]:
        """For each plugin, the names it registers per kind (for ``catenary plugins``)."""
        for collect in (
            self.wire_types,
            self.limit_policies,
            self.sources,
            self.vehicle_sources,
            self.processors,
            self.reporters,
            self.notifiers,
            self.commands,
            self.config_sections,
        ):
            collect()
        table: dict[str, dict[str, list[str]]] = {name: {} for name in self.plugin_names}
        for (kind, item), plugin in self._owner.items():
            table.setdefault(plugin, {}).setdefault(kind, []).append(item)
        return table

    def _notify(self, hook: str, kwargs: Mapping[str, Any]) -> None:
        caller = getattr(self._pm.hook, hook)
        for impl in caller.get_hookimpls():  # load order
            call: Callable[..., Any] = impl.function
            try:
                call(**kwargs)
            except Exception as exc:
                self.errors.append(PluginError(impl.plugin_name, hook, one_line(exc)))

    def run_stored(self, run_id: int, database_url: str) -> None:
        """Tell every plugin that a run was committed."""
        self._notify("catenary_run_stored", {"run_id": run_id, "database_url": database_url})

    def alert_raised(self, alert: AlertRecord) -> None:
        """Tell every plugin that an alert was committed."""
        self._notify("catenary_alert_raised", {"alert": alert})


__all__ = ["PluginError", "PluginFailure", "PluginRegistry", "plugin_errors"]
