"""The HTML reports in a real browser: headless Chromium renders them without an error.

Each report is rendered from a ``file://`` address with every network feature off; the
screenshot must be a real picture (large enough, not blank), the browser's log must hold no
console message (a script error or a resource it failed to load), and the DOM Chromium built
must hold the report's parts. Chromium is the Debian package (``.ci/run`` installs it); a
machine without it fails here rather than skipping.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from matplotlib import image

from catenary.cli import cli

pytestmark = [
    pytest.mark.slow,
    pytest.mark.parametrize("database_url", ["sqlite"], indirect=True),  # pages, not backends
]

WINDOW = (1280, 2000)
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-logging=stderr",
    "--v=0",
)
CONSOLE_PROBLEMS = ("CONSOLE", "Uncaught", "Failed to load resource", "net::ERR_")


def chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        pytest.fail(
            "chromium is not installed: the browser test needs it "
            "(apt-get install chromium; .ci/run installs it)"
        )
    return found


def browse(page: Path, profile: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    """Chromium on ``page`` with its own profile folder; fails the test on a bad exit."""
    done = subprocess.run(
        [chromium(), *FLAGS, f"--user-data-dir={profile}", *extra, page.resolve().as_uri()],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    problems = [
        line for line in done.stderr.splitlines() if any(p in line for p in CONSOLE_PROBLEMS)
    ]
    assert problems == [], "\n".join(problems)
    return done


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def check_rendered(page: Path, tmp_path: Path, expected: list[str]) -> np.ndarray:
    """Screenshot ``page`` and check it; check the DOM holds ``expected``; the pixels."""
    shot = tmp_path / f"{page.stem}.png"
    width, height = WINDOW
    browse(
        page,
        tmp_path / f"profile-{page.stem}-shot",
        f"--screenshot={shot}",
        f"--window-size={width},{height}",
    )
    assert shot.stat().st_size > 50_000
    pixels = image.imread(shot)[..., :3]
    assert pixels.shape[:2] == (height, width)
    assert float(pixels.std()) > 0.05  # not blank
    ink = np.mean(np.any(pixels < 0.8, axis=-1))
    assert 0.02 < ink < 0.6, ink  # text, tables and plots on a white page
    dom = browse(page, tmp_path / f"profile-{page.stem}-dom", "--dump-dom").stdout
    for part in expected:
        assert part in dom, part
    return pixels


def test_the_run_report_renders_in_chromium(database: str, config: Path, tmp_path: Path) -> None:
    page = tmp_path / "run.html"
    result = invoke("--config", config, "--db", database, "report", "run", "1", "-o", page)
    assert result.exit_code == 0, result.output
    pixels = check_rendered(
        page,
        tmp_path,
        ['id="facts"', "<svg", ">12/03<", 'id="exceedances"', 'id="spans"', "critical"],
    )
    # the plots' lines: the wires' blue and orange are on the page
    blue = np.all(np.abs(pixels - np.array([0x1F, 0x6F, 0xB4]) / 255) < 0.1, axis=-1)
    orange = np.all(np.abs(pixels - np.array([0xF0, 0x7F, 0x0E]) / 255) < 0.1, axis=-1)
    assert np.count_nonzero(blue) > 500 and np.count_nonzero(orange) > 500


def test_the_maintenance_report_renders_in_chromium(alerts: str, tmp_path: Path) -> None:
    page = tmp_path / "maintenance.html"
    result = invoke("--db", alerts, "report", "maintenance", "--line", "demo-line", "-o", page)
    assert result.exit_code == 0, result.output
    check_rendered(
        page,
        tmp_path,
        ['id="alerts-critical"', 'id="forecasts"', 'id="visits"', "masts 12/02 to 12/03"],
    )


def test_the_run_report_prints_each_section_on_its_own_pages(
    database: str, config: Path, tmp_path: Path
) -> None:
    page = tmp_path / "run.html"
    args = ["report", "run", "1", "--set", "segment_m=100", "-o", page]
    result = invoke("--config", config, "--db", database, *args)
    assert result.exit_code == 0, result.output
    text = page.read_text(encoding="utf-8")
    unstyled = tmp_path / "unstyled.html"  # the same page without its print styles
    unstyled.write_text(re.sub(r"@media print \{.*?\n\}\n", "", text, flags=re.S))
    assert "@media print" in text and "@media print" not in unstyled.read_text()

    def printed_pages(html: Path) -> int:
        pdf = html.with_suffix(".pdf")
        profile = tmp_path / f"profile-print-{html.stem}"
        browse(html, profile, f"--print-to-pdf={pdf}", "--no-pdf-header-footer")
        return len(re.findall(rb"/Type\s*/Page\b(?!s)", pdf.read_bytes()))

    pages = printed_pages(page)
    # four sections, each from a new page (the three figures and the span table may take more)
    assert 4 <= pages <= 12, pages
    assert printed_pages(unstyled) < pages
    # on screen the same page is one long document with its contents at the top
    dom = browse(page, tmp_path / "profile-screen", "--dump-dom").stdout
    assert dom.index('id="contents"') < dom.index('id="run"')
