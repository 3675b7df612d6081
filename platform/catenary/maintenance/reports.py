"""Report requests: what a reporter's ``write(request, output_path)`` is given
(``catenary.plugins.ReportRequest``), made alike by ``catenary report`` and by scheduled
report jobs."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

from catenary.config import Settings
from catenary.limits import choose_policy
from catenary.plugins.types import ReportRequest

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
) -> ReportRequest:
    """The request a reporter's ``write`` takes; ``policy`` names a preset (default: the
    config's ``[limits]``, else each wire type's standard limit, as alerts are evaluated)."""
    return ReportRequest(
        settings=settings,
        registry=registry,
        policy=choose_policy(
            settings, registry.limit_policies(), policy, wire_types=registry.wire_types()
        ),
        runs=tuple(runs),
        line=line,
        track=track,
        options=dict(options or {}),
    )
