"""Errors a user can cause: the CLI prints them as one line and exits non-zero."""

from __future__ import annotations


class UserError(Exception):
    """A problem with the user's input (a file, a field, a value, a setting).

    The message is one line naming the file, field and value; the CLI prints it without a
    traceback and exits with status 2.
    """


class FormatError(UserError):
    """A file does not follow its layout in FORMATS.md."""

    def __init__(self, path: object, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = path
        self.problem = problem


class DatabaseNotMigrated(UserError):
    """The database's schema is not at the revision this version of catenary needs."""


def one_line(exc: BaseException) -> str:
    """``Type: message`` of an exception, its message's whitespace (newlines) collapsed."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
