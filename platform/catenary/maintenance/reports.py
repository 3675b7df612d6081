"""Report requests: what a reporter's ``write(request, output_path)`` is given.

Reporters come from plugins (hook ``catenary_reporters``; the built-ins are in
``catenary_reports``), so a third party's reporter is run exactly like the built-ins, by
``catenary report`` and by scheduled report jobs. The request (``report_request``) is a
mapping with the keys:

- ``settings``: the ``Settings`` of the invocation (database URL, data directory, sections);
- ``registry``: the ``PluginRegistry`` (wire types, limit policies);
- ``policy``: the wear-limit ``LimitPolicy`` (``--policy NAME``, else the config's
  ``[limits]``), or None without one;
- ``runs``: the run references given (ids or ``latest``), a tuple of str;
- ``line``, ``track``: codes, or None;
- ``options``: the ``--set KEY=VALUE`` pairs, a dict of str.

A reporter chooses its output's format by the file's suffix and refuses, in one line, what it
does not take.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from catenary.config import Settings
from catenary.limits import choose_policy

if TYPE_CHECKING:
    from catenary.plugins import PluginRegistry

__all__ = ["report_request"]


def report_request(
    settings: Settings,
    registry: PluginRegistry,
    *,
    runs: tuple[str, ...] = (),
    line: str | None = None,
    track: str | None = None,
    policy: str | None = None,
    options: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The request a reporter's ``write`` takes (module docstring); ``policy`` names a preset
    (default: the config's ``[limits]``)."""
    return {
        "settings": settings,
        "registry": registry,
        "policy": choose_policy(settings, registry.limit_policies(), policy),
        "runs": tuple(runs),
        "line": line,
        "track": track,
        "options": dict(options or {}),
    }
