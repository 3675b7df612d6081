"""The plugin API: what a catenary plugin imports, and only from here.

- ``hookimpl``: the marker for a plugin's hook implementations (the hooks, each with an
  example: ``catenary.plugins.hookspecs``);
- the registrations a contribution hook returns (``types``): ``WireType``, ``LimitPolicy``,
  ``Source``, ``VehicleSource``, ``Processor``, ``Reporter``, ``Notifier``, ``Command``,
  ``ConfigSection``, and
  the protocols their callables return (``ScanStream``, ``VehicleStream``,
  ``BlockProcessor``, and the optional ``RunChecker``, ``ImageLocator``,
  ``StagedProcessor`` and ``WireTypesUser``);
- the payloads the core hands over: ``ReportRequest`` (reporters), ``AlertRecord``
  (notifiers, ``catenary_alert_raised``), and the domain types of ``catenary.domain``;
- ``CommandContext`` and ``pass_command_context`` (``context``): what a plugin's command
  receives (settings, registry, database) instead of importing the CLI, and
  ``database_option``, the ``--db URL`` of a command that touches the database;
- ``PluginRegistry`` (``manager``): the core's only caller of the hooks, with its error
  boundary (``PluginRegistry.boundary``, ``PluginFailure``) and the load errors
  (``PluginError``).
"""

from catenary.limits import LimitPolicy
from catenary.plugins.context import CommandContext, database_option, pass_command_context
from catenary.plugins.hookspecs import hookimpl
from catenary.plugins.manager import PluginError, PluginFailure, PluginRegistry
from catenary.plugins.types import (
    AlertRecord,
    BlockProcessor,
    Command,
    ConfigSection,
    ImageLocator,
    Notifier,
    Processor,
    Reporter,
    ReportRequest,
    RunChecker,
    ScanStream,
    Source,
    StagedProcessor,
    VehicleSource,
    VehicleStream,
    WireTypesUser,
)
from catenary.wiretype import WireType

__all__ = [
    "AlertRecord",
    "BlockProcessor",
    "Command",
    "CommandContext",
    "ConfigSection",
    "ImageLocator",
    "LimitPolicy",
    "Notifier",
    "PluginError",
    "PluginFailure",
    "PluginRegistry",
    "Processor",
    "ReportRequest",
    "Reporter",
    "RunChecker",
    "ScanStream",
    "Source",
    "StagedProcessor",
    "VehicleSource",
    "VehicleStream",
    "WireType",
    "WireTypesUser",
    "database_option",
    "hookimpl",
    "pass_command_context",
]
