"""The plugin API: what a catenary plugin imports, and only from here.

- ``hookimpl``: the marker for a plugin's hook implementations (the hooks: ``hookspecs``);
- the registration types a contribution hook returns (``types``): ``WireType``,
  ``LimitPolicy``, ``Source``, ``VehicleSource``, ``Processor``, ``Reporter``, ``Notifier``,
  ``Command``, and the protocols their callables return;
- ``CommandContext`` and ``pass_command_context`` (``context``): what a plugin's command
  receives (settings, registry, database) instead of importing the CLI;
- ``PluginRegistry`` (``manager``): the core's only caller of the hooks, and ``PluginError``.
"""

from catenary.limits import LimitPolicy
from catenary.plugins.context import CommandContext, pass_command_context
from catenary.plugins.hookspecs import hookimpl
from catenary.plugins.manager import PluginError, PluginRegistry
from catenary.plugins.types import (
    BlockProcessor,
    Command,
    Notifier,
    Processor,
    Reporter,
    ScanStream,
    Source,
    VehicleSource,
    VehicleStream,
)
from catenary.wiretype import WireType

__all__ = [
    "BlockProcessor",
    "Command",
    "CommandContext",
    "LimitPolicy",
    "Notifier",
    "PluginError",
    "PluginRegistry",
    "Processor",
    "Reporter",
    "ScanStream",
    "Source",
    "VehicleSource",
    "VehicleStream",
    "WireType",
    "hookimpl",
    "pass_command_context",
]
