"""The robustness suite: bad input, faults and concurrency, each case checking what a user
needs: one clear line and a non-zero exit, no traceback, no secret, nothing half-written, nothing
lost, and the next command working.

Every test here is marked ``robustness`` (``pytest -m robustness`` runs the suite alone). The
commands run as a user runs them: ``catenary`` in a child process, with this test's isolated
environment (``tests/conftest.py``).
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import IO

import pytest
from hypothesis import HealthCheck, settings

from catenary.errors import UserError

# the start of a terminal escape sequence (ESC, or the 8-bit CSI/OSC) never reaches a terminal raw
RAW_ESCAPES = ("\x1b", "\x9b", "\x9d")
USAGE_EXIT_CODE = 2


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    here = Path(__file__).parent
    for item in items:
        if here in Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.robustness)


def catenary(
    *args: str | os.PathLike[str],
    env: Mapping[str, str] | None = None,
    cwd: Path | None = None,
    timeout: float = 120.0,
    input: str | None = None,
    preexec_fn: Callable[[], None] | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run ``catenary ARGS`` in a child process and return what it printed and its exit code.

    ``env`` adds to (or overrides) this process's environment, which the autouse fixture of
    ``tests/conftest.py`` has already isolated; ``preexec_fn`` is called in the child before
    the command starts (``hardening_support.file_size_limit``, ``without_root_file_access``).
    """
    return subprocess.run(
        _command(args),
        env={**os.environ, **(env or {})},
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        input=input,
        preexec_fn=preexec_fn,
    )


def start_catenary(
    *args: str | os.PathLike[str],
    env: Mapping[str, str] | None = None,
    stdout: int | IO[str] = subprocess.PIPE,
    stderr: int | IO[str] = subprocess.PIPE,
    new_session: bool = False,
) -> subprocess.Popen[str]:
    """Start ``catenary ARGS`` in a child process, as ``catenary`` runs it, and return at once;
    its output goes to ``stdout`` and ``stderr`` (pipes of text by default), its input is empty.
    ``new_session``: in a session and process group of its own (whose id is its pid), which
    the processes it starts share.
    """
    return subprocess.Popen(
        _command(args),
        env={**os.environ, **(env or {})},
        stdin=subprocess.DEVNULL,
        stdout=stdout,
        stderr=stderr,
        text=True,
        start_new_session=new_session,
    )


def finished(
    process: subprocess.Popen[str], timeout: float = 120.0
) -> subprocess.CompletedProcess[str]:
    """What a started ``catenary`` printed and its exit code, once it has ended."""
    out, err = process.communicate(timeout=timeout)
    return subprocess.CompletedProcess(process.args, process.returncode, out, err)


def _command(args: Sequence[str | os.PathLike[str]]) -> list[str]:
    return [sys.executable, "-m", "catenary.cli", *map(str, args)]


@pytest.fixture(scope="module")
def examples_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of the module's own for the files of hypothesis examples (which share the
    fixtures of their test: a function-scoped one is refused)."""
    return tmp_path_factory.mktemp("examples")


def examples(max_examples: int) -> settings:
    """Hypothesis settings of a property test here: ``max_examples`` examples, the same ones
    at every run, however slow their generation. No deadline: on a loaded machine hypothesis's
    timing of an example is noise; a test that must not hang bounds the call it checks (e.g.
    ``time_limit`` in ``test_run_file_fuzz``)."""
    return settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        suppress_health_check=[HealthCheck.too_slow],
    )


def assert_names_file(error: UserError, path: Path) -> str:
    """Check that ``error`` (a file refused) is one line starting with ``path``; return it."""
    message = str(error)
    assert "\n" not in message, message
    assert message.startswith(f"{path}: "), message
    return message


def assert_refused(
    result: subprocess.CompletedProcess[str],
    *expected: str,
    secrets: Sequence[str] = (),
) -> str:
    """Check that a command was refused as a user needs: a non-zero exit, one line on stderr
    holding each of ``expected`` (case-insensitive; a usage error's line comes after click's
    usage and hint), no traceback, no raw escape sequence and none of ``secrets`` anywhere in
    its output. Returns the line."""
    output = result.stdout + result.stderr
    assert result.returncode not in (0, None), output
    assert "Traceback" not in output, output
    assert not any(escape in output for escape in RAW_ESCAPES), repr(output)
    for secret in secrets:
        assert secret not in output, output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    if result.returncode == USAGE_EXIT_CODE:  # click's usage and hint lines come before it
        lines = [line for line in lines if not line.startswith(("Usage: ", "Try '"))]
    assert len(lines) == 1, result.stderr
    for word in expected:
        assert word.lower() in lines[0].lower(), lines[0]
    return lines[0]


def assert_succeeded(result: subprocess.CompletedProcess[str]) -> None:
    """Check that a command worked: exit 0, no traceback, no raw escape sequence."""
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    assert "Traceback" not in output, output
    assert not any(escape in output for escape in RAW_ESCAPES), repr(output)
