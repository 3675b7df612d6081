"""A third party adds a wire type by publishing a package with an entry point: nothing else.

The package in ``thirdparty/`` is really installed (``pip install --target``) into a folder
that only the subprocesses below see on their ``PYTHONPATH``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).parent / "thirdparty"


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The third-party package installed into a folder of its own."""
    work = tmp_path_factory.mktemp("thirdparty")
    source = work / "src"  # build from a copy: setuptools writes build/ and egg-info in place
    shutil.copytree(PACKAGE, source, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    target = work / "site"
    command = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index"]
    command += ["--no-build-isolation", "--no-cache-dir", "--disable-pip-version-check"]
    subprocess.run([*command, "--target", str(target), str(source)], check=True, timeout=300)
    assert list(target.glob("catenary_xw_wires-*.dist-info"))
    return target


def _catenary(site: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(site))
    return subprocess.run(
        [sys.executable, "-m", "catenary.cli", *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_plugins_lists_the_third_party_wire_type(site: Path) -> None:
    result = _catenary(site, "plugins", "--strict")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert "xw" in lines
    assert lines[lines.index("xw") + 1].strip() == "wire type: XW-95"
    assert "wiretypes" in lines  # the built-ins are still there


def test_wire_types_lists_it_with_its_plugin(site: Path) -> None:
    result = _catenary(site, "wire-types")
    assert result.returncode == 0, result.stderr
    (row,) = [line for line in result.stdout.splitlines() if line.startswith("XW-95")]
    assert row.split()[-1] == "xw"
    assert any(line.startswith("CTA120") for line in result.stdout.splitlines())


def test_presets_apply_to_the_third_party_wire_type(site: Path) -> None:
    result = _catenary(site, "wire-types", "XW-95", "--policy", "manufacturer-30pct")
    assert result.returncode == 0, result.stderr
    assert "XW-95: Example Works XW; plugin xw" in result.stdout
    assert "critical" in result.stdout


def test_without_the_package_it_is_not_there(tmp_path: Path) -> None:
    result = _catenary(tmp_path, "wire-types")
    assert result.returncode == 0, result.stderr
    assert "XW-95" not in result.stdout
