"""A reporter's request (``catenary.plugins.ReportRequest``), checked against what the reporter
takes."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from catenary.config import Settings
from catenary.errors import UserError
from catenary.limits import LimitPolicy
from catenary.plugins import PluginRegistry, ReportRequest

__all__ = ["Request", "check_output", "parse_request"]


@dataclass(frozen=True)
class Request:
    """A checked request; ``options`` holds every option the reporter takes, as numbers."""

    settings: Settings
    registry: PluginRegistry
    policy: LimitPolicy | None
    runs: tuple[str, ...]
    line: str | None
    track: str | None
    options: Mapping[str, float]


def parse_request(
    reporter: str,
    raw: ReportRequest,
    *,
    runs: tuple[int, int] = (0, 0),
    line: bool = False,
    options: Mapping[str, float] | None = None,
) -> Request:
    """Check ``raw`` for reporter ``reporter``: between ``runs[0]`` and ``runs[1]`` runs, a
    line (and track) only if ``line``, and only the positive numeric ``options`` named, whose
    values here are the defaults."""
    where = f"reporter {reporter!r}"
    given = tuple(str(r) for r in raw.runs)
    fewest, most = runs
    if not fewest <= len(given) <= most:
        if most == 0:
            wanted = "no RUN"
        elif fewest == most:
            wanted = f"{most} RUN{'s' if most > 1 else ''}"
        else:
            wanted = f"{fewest} to {most} RUNs"
        raise UserError(f"{where} takes {wanted}, not {len(given)} ({' '.join(given) or 'none'})")
    line_code, track_code = raw.line, raw.track
    if not line and (line_code is not None or track_code is not None):
        raise UserError(f"{where} takes no --line or --track")
    defaults = dict(options or {})
    values = dict(defaults)
    for key, text in raw.options.items():
        if key not in defaults:
            known = ", ".join(sorted(defaults)) or "none"
            raise UserError(f"{where}: unknown option {key!r} (known: {known})")
        try:
            value = float(text)
        except (TypeError, ValueError):
            value = math.nan
        if not (math.isfinite(value) and value > 0.0):
            raise UserError(f"{where}: option {key} = {text!r} is not a positive number")
        values[key] = value
    return Request(
        settings=raw.settings,
        registry=raw.registry,
        policy=raw.policy,
        runs=given,
        line=line_code,
        track=track_code,
        options=values,
    )


def check_output(output: Path, suffixes: tuple[str, ...]) -> str:
    """The output's suffix, lower case, if it is one of ``suffixes`` and its folder exists;
    else a ``UserError``."""
    suffix = output.suffix.lower()
    if suffix not in suffixes:
        raise UserError(f"{output}: the output's suffix must be {' or '.join(suffixes)}")
    if not output.parent.is_dir():
        raise UserError(f"{output}: no folder {output.parent}")
    return suffix
