"""The third-party files the service serves (``web/static/vendor``): each is used by a
template, listed with its package, version and licence in the folder's README, has its
licence beside it, and is in the distribution's package data."""

from __future__ import annotations

import fnmatch
import re
import tomllib
from pathlib import Path

import catenary.web

WEB = Path(catenary.web.__file__).parent
VENDOR = WEB / "static" / "vendor"
ROOT = Path(__file__).resolve().parents[2]


def served() -> list[Path]:
    """The vendored files a page links: scripts and styles."""
    return sorted(p for p in VENDOR.iterdir() if p.suffix in (".js", ".css"))


def test_every_vendored_file_is_linked_from_a_template() -> None:
    templates = "\n".join(p.read_text() for p in (WEB / "templates").glob("*.html"))
    assert served(), "no vendored files"
    for path in served():
        assert f'"/static/vendor/{path.name}"' in templates, f"{path.name} is not used"


def test_every_vendored_file_has_its_package_version_and_licence() -> None:
    readme = (VENDOR / "README.md").read_text()
    for path in VENDOR.iterdir():
        if path.name == "README.md":
            continue
        (row,) = [line for line in readme.splitlines() if line.startswith(f"| `{path.name}` |")]
        version = re.search(r"-(\d+\.\d+\.\d+)\.", path.name)
        assert version is not None, f"{path.name}: no version in its name"
        assert f"| {version.group(1)} |" in row
        if path.suffix in (".js", ".css"):
            licence = re.search(r"`([^`]+\.LICENSE)`", row)
            assert licence is not None, f"{path.name}: no licence file named"
            assert (VENDOR / licence.group(1)).read_text().strip()
            assert "MIT" in row
    assert "sha512-" in readme  # the npm tarball's integrity


def test_no_vendored_file_reaches_outside() -> None:
    for path in served():
        text = path.read_text()
        # a comment may name the project's home; nothing is loaded from anywhere
        assert not re.search(r"""(?:import\s*\(|url\()\s*["']?(?:https?:)?//""", text), path.name


def test_the_distribution_holds_the_vendored_files_and_the_track_view() -> None:
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = setuptools["package-data"]["catenary.web"]
    files = [
        *VENDOR.iterdir(),
        WEB / "static" / "track.js",
        WEB / "static" / "track.css",
        WEB / "templates" / "track.html",
    ]
    for path in files:
        relative = path.relative_to(WEB).as_posix()
        assert any(fnmatch.fnmatch(relative, p) for p in patterns), relative
