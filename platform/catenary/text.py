"""Text from outside: control characters refused in identifiers, escaped in terminal output.

An identifier (a line, track, mast or anchor section code, a name given with ``--by``) is
printable text (FORMATS.md): a control character (C0 with CR, LF and ESC, DEL, C1) in one
is refused where it comes in. Text echoed to a terminal goes through ``printable``, so a name
stored before that rule (or any other stored text) cannot move the cursor or retitle the
window.
"""

from __future__ import annotations

import re
from typing import Any

from catenary.errors import UserError

_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """``text`` with each control character escaped as ``repr`` does (``\\x1b``, ``\\n``...)."""
    return _CONTROL.sub(lambda match: repr(match.group())[1:-1], text)


def control_character_problem(field: str, value: str) -> str | None:
    """None for an identifier without control characters, else the problem in words."""
    if _CONTROL.search(value) is None:
        return None
    return f"{field} = {value!r} holds a control character (identifiers are printable text)"


def identifier_option(ctx: Any, param: Any, value: str | None) -> str | None:
    """A click option callback: the option's identifier, or a ``UserError`` naming the
    option when it holds a control character."""
    problem = None if value is None else control_character_problem(param.opts[0], value)
    if problem is not None:
        raise UserError(problem)
    return value
