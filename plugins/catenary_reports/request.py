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
from catenary.measurement.samples import STDOUT, one_of
from catenary.plugins import PluginRegistry, ReportRequest

__all__ = ["Option", "Request", "check_output", "parse_request"]


@dataclass(frozen=True)
class Option:
    """A numeric ``--set KEY=VALUE`` option: its default and the values it may take, from
    ``low`` to ``high`` inclusive (bounds that keep the work a report does in proportion)."""

    default: float
    low: float
    high: float
    unit: str


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
    options: Mapping[str, Option] | None = None,
) -> Request:
    """Check ``raw`` for reporter ``reporter``: between ``runs[0]`` and ``runs[1]`` runs, a
    line (and track) only if ``line``, and only the numeric ``options`` named, each within its
    bounds (a ``UserError`` naming the option, the value and the range)."""
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
    known = dict(options or {})
    values = {key: option.default for key, option in known.items()}
    for key, text in raw.options.items():
        option = known.get(key)
        if option is None:
            names = ", ".join(sorted(known)) or "none"
            raise UserError(f"{where}: unknown option {key!r} (known: {names})")
        try:
            value = float(text)
        except (TypeError, ValueError):
            value = math.nan
        if not option.low <= value <= option.high:  # NaN too
            raise UserError(
                f"{where}: option {key} = {text!r} is outside {option.low:.15g} to "
                f"{option.high:.15g} {option.unit}"
            )
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
    """The output's suffix, lower case, if it is one of ``suffixes`` and its folder exists
    (``-``, standard output: ``.csv`` if it is one of them); else a ``UserError``."""
    if str(output) == STDOUT and ".csv" in suffixes:
        return ".csv"
    suffix = output.suffix.lower()
    if suffix not in suffixes:
        raise UserError(f"{output}: the output's suffix must be {one_of(suffixes)}")
    if not output.parent.is_dir():
        raise UserError(f"{output}: no folder {output.parent}")
    return suffix
