"""What one invocation of ``catenary`` shares, and how its errors are printed.

The invocation's ``CommandContext`` (settings and plugin registry, made on first use; plugin
commands receive the same) is kept on the root context; every command reaches it through
``app_of(ctx)``. Errors a user can cause (``UserError`` and its
kinds, unreadable files, values outside a profile) are printed as one line without a
traceback, with exit status 1; usage errors exit 2.
"""

from __future__ import annotations

import copy
import signal
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

import click

from catenary.errors import UserError
from catenary.plugins.context import CommandContext
from catenary.wiretype import ProfileRangeError

INTERRUPTED_EXIT_CODE = 130
"""Exit status of a command stopped by Ctrl-C after keeping what it had done (the shell's
convention)."""
TERMINATED_EXIT_CODE = 143
"""Exit status of a command stopped by SIGTERM the same way (128 + 15)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C raises ``KeyboardInterrupt`` (``Interruptions``)."""


class Interruptions:
    """Ctrl-C and SIGTERM during a command (``handled()``): each raises where it lands
    (``KeyboardInterrupt``, ``Terminated``: SIGTERM stops the command as Ctrl-C does, what is
    committed kept, scratch files removed; Python's default would end the process at once,
    cleaning nothing) and is kept in ``received``. One that lands where Python only prints
    it (a weakref callback, a ``__del__``) is not printed, and is raised again by the
    command's next ``check()``.
    """

    def __init__(self) -> None:
        self.received: KeyboardInterrupt | None = None

    def check(self) -> None:
        if self.received is not None:
            raise self.received

    @contextmanager
    def handled(self) -> Iterator[None]:
        def interrupt(signum: int, frame: FrameType | None) -> None:
            self.received = Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
            raise self.received

        def unraisable(unraisable: sys.UnraisableHookArgs) -> None:
            if unraisable.exc_value is not self.received:
                hook(unraisable)

        hook = sys.unraisablehook
        previous = {number: signal.signal(number, interrupt) for number in _INTERRUPTIONS}
        sys.unraisablehook = unraisable
        try:
            yield
        finally:
            sys.unraisablehook = hook
            for number, handler in previous.items():
                signal.signal(number, handler)


_INTERRUPTIONS = (signal.SIGINT, signal.SIGTERM)


def interrupted_exit_code(interruption: KeyboardInterrupt) -> int:
    """130 for Ctrl-C, 143 for SIGTERM."""
    return TERMINATED_EXIT_CODE if isinstance(interruption, Terminated) else INTERRUPTED_EXIT_CODE


def app_of(ctx: click.Context) -> CommandContext:
    """The invocation's ``CommandContext``, kept on the root context."""
    root = ctx.find_root()
    if not isinstance(root.obj, CommandContext):
        root.obj = CommandContext(root.params.get("config_path"), root.params.get("database_url"))
    return root.obj


def one_line_errors(call: Callable[[], Any]) -> Any:
    """Run ``call``, turning errors a user can cause into a one-line ``ClickException``."""
    try:
        return call()
    except (UserError, ProfileRangeError) as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        raise click.ClickException(f"{where}{exc.strerror or exc}") from None


class CatenaryGroup(click.Group):
    """The root group: its commands include the plugins', and its errors are one line."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        names = set(super().list_commands(ctx))
        names |= set(one_line_errors(lambda: app_of(ctx).registry.commands()))
        return sorted(names)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        command = super().get_command(ctx, cmd_name)
        if command is None:
            found = one_line_errors(lambda: app_of(ctx).registry.commands()).get(cmd_name)
            command = None if found is None else _bounded(found.command, cmd_name)
        return command

    def invoke(self, ctx: click.Context) -> Any:
        return one_line_errors(lambda: super(CatenaryGroup, self).invoke(ctx))


def _bounded(command: click.Command, name: str) -> click.Command:
    """A plugin's command (a copy: the plugin's own object is left alone) that runs inside the
    plugins' error boundary, naming its plugin."""
    bounded = copy.copy(command)

    def invoke(ctx: click.Context) -> Any:
        with app_of(ctx).registry.boundary("command", name):
            return command.invoke(ctx)

    bounded.invoke = invoke  # type: ignore[method-assign]
    return bounded
