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
from collections.abc import Mapping, Sequence
from pathlib import Path

import pytest

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
) -> subprocess.CompletedProcess[str]:
    """Run ``catenary ARGS`` in a child process and return what it printed and its exit code.

    ``env`` adds to (or overrides) this process's environment, which the autouse fixture of
    ``tests/conftest.py`` has already isolated.
    """
    return subprocess.run(
        [sys.executable, "-m", "catenary.cli", *map(str, args)],
        env={**os.environ, **(env or {})},
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        input=input,
    )


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
