"""Text from outside: control characters and overlong values refused in identifiers, control
characters escaped in terminal output.

An identifier (a line, track, mast or anchor section code, a name given with ``--by``) is
printable text (FORMATS.md): a control character (C0 with CR, LF and ESC, DEL, C1) in one
is refused where it comes in, and so is one longer than the database column that keeps it
(the lengths of ``catenary.domain``). Text echoed to a terminal goes through ``printable``,
so a name stored before that rule (or any other stored text) cannot move the cursor or
retitle the window.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

from catenary.errors import UserError

CONTROL_PATTERN = r"[\x00-\x1f\x7f-\x9f]"
"""A control character (C0 with CR, LF and ESC, DEL, C1), as a regular expression that Python and
RE2 (pyarrow) read alike."""
_CONTROL = re.compile(CONTROL_PATTERN)


def printable(text: str) -> str:
    """``text`` with each control character escaped as ``repr`` does (``\\x1b``, ``\\n``...)."""
    return _CONTROL.sub(lambda match: repr(match.group())[1:-1], text)


def control_character_problem(field: str, value: str) -> str | None:
    """None for an identifier without control characters, else the problem in words."""
    if _CONTROL.search(value) is None:
        return None
    return f"{field} = {value!r} holds a control character (identifiers are printable text)"


def length_problem(field: str, value: str, limit: int) -> str | None:
    """None when ``value`` fits a column of ``limit`` characters, else the problem in words
    (without the value, which may be long)."""
    if len(value) <= limit:
        return None
    return f"{field} is {len(value)} characters long (at most {limit})"


def identifier_problem(field: str, value: str, limit: int) -> str | None:
    """None for an identifier of at most ``limit`` characters without control characters,
    else the problem in words."""
    return length_problem(field, value, limit) or control_character_problem(field, value)


def identifier_option(limit: int) -> Callable[[Any, Any, str | None], str | None]:
    """A click option callback for an identifier kept in a column of ``limit`` characters:
    the option's value, or a ``UserError`` naming the option when it is too long or holds a
    control character."""

    def check(ctx: Any, param: Any, value: str | None) -> str | None:
        problem = None if value is None else identifier_problem(param.opts[0], value, limit)
        if problem is not None:
            raise UserError(problem)
        return value

    return check


def utc_text(moment: datetime | None) -> str | None:
    """``moment`` as ISO 8601 in UTC (a naive time is UTC, as the database stores it)."""
    if moment is None:
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return moment.astimezone(UTC).isoformat()
