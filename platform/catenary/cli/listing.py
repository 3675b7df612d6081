"""``--format json`` of the listing commands: one JSON document on standard output, a list of
objects (one object for a single thing), keys stable, times ISO 8601 in UTC, numbers as
stored (unrounded; NaN as null), every character outside ASCII escaped (so no control
character reaches a terminal raw)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from datetime import datetime
from typing import Any, TypeVar

import click

from catenary.text import utc_text

__all__ = ["FORMATS", "echo_json", "format_option", "utc_text"]

FORMATS = ("text", "json")
"""What a listing command prints: a table for people, or JSON for programs."""

F = TypeVar("F", bound=Callable[..., Any])


def format_option(*more: str) -> Callable[[F], F]:
    """The ``--format`` option (``FORMATS`` and ``more``; default text), passed as
    ``output_format``."""
    return click.option(
        "--format",
        "output_format",
        type=click.Choice([*FORMATS, *more]),
        default="text",
        show_default=True,
        help="text: a table for people; json: for programs (README, File formats).",
    )


def _plain(value: Any) -> Any:
    """``value`` with its times as text and its NaN and infinities as null, recursively."""
    if isinstance(value, datetime):
        return utc_text(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def echo_json(document: Any) -> None:
    """Print ``document`` (a list of objects, or one object) as JSON (module docstring)."""
    click.echo(json.dumps(_plain(document), indent=1, allow_nan=False))
