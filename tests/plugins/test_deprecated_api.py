"""A plugin written against catenary 0.1's import paths and mapping payloads still loads and
works for one release, with a ``DeprecationWarning`` naming each new place."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

OLD_PLUGIN = """
import click

from catenary import hookimpl
from catenary.alerts import alert_record
from catenary.cli import app_of
from catenary.hookspecs import PROJECT
from catenary.registrations import Command, Notifier, Reporter
from catenary.report_command import report_request

assert PROJECT == "catenary" and callable(alert_record)


@click.command("old-hello")
@click.pass_context
def hello(ctx):
    app = app_of(ctx)
    request = report_request(app.settings, app.registry, runs=("7",), line="L1")
    click.echo(f"runs {request['runs'][0]} line {request.get('line')}")


def write(request, output):
    output.write_text(",".join(request["runs"]) + " " + str(request["options"]))
    return output


def send(alert, settings):
    raise RuntimeError(alert["line"])


@hookimpl
def catenary_commands():
    return [Command("old-hello", hello)]


@hookimpl
def catenary_reporters():
    return [Reporter("old-report", "written for catenary 0.1", write)]


@hookimpl
def catenary_notifiers():
    return [Notifier("old-notifier", "written for catenary 0.1", send)]
"""


def _install(site: Path) -> None:
    """The plugin as a distribution with an entry point, as a third party ships it."""
    info = site / "old_plugin-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: old-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[catenary.plugins]\nold = old_plugin\n")
    (site / "old_plugin.py").write_text(textwrap.dedent(OLD_PLUGIN))


def _catenary(site: Path, tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    code = "import sys; from catenary.cli import main; main(sys.argv[1:])"
    return subprocess.run(
        [sys.executable, "-W", "always::DeprecationWarning", "-c", code, *args],
        capture_output=True,
        text=True,
        timeout=120,
        env={
            "PATH": "/usr/bin:/bin",
            "PYTHONPATH": str(site),
            "HOME": str(tmp_path),
            "CATENARY_DATA_DIR": str(tmp_path / "data"),
        },
    )


def test_a_plugin_written_for_0_1_loads_runs_and_is_warned(tmp_path: Path) -> None:
    site = tmp_path / "site"
    _install(site)
    plugins = _catenary(site, tmp_path, "plugins", "--strict")
    assert plugins.returncode == 0, plugins.stderr
    assert "command: old-hello" in plugins.stdout and "reporter: old-report" in plugins.stdout
    for old, new in (
        ("catenary.hookimpl", "catenary.plugins.hookimpl"),
        ("catenary.alerts", "catenary.maintenance.alerts"),
        ("catenary.hookspecs", "catenary.plugins.hookspecs"),
        ("catenary.registrations", "catenary.plugins"),
        ("catenary.report_command", "catenary.maintenance.reports"),
    ):
        assert (
            f"DeprecationWarning: {old} is deprecated and goes in the next release: use {new}"
            in (plugins.stderr)
        )

    hello = _catenary(site, tmp_path, "old-hello")
    assert hello.returncode == 0, hello.stderr
    assert hello.stdout.strip() == "runs 7 line L1"
    assert "catenary.cli.app_of is deprecated" in hello.stderr
    assert "ReportRequest['runs'] is deprecated: read the attribute .runs" in hello.stderr

    out = tmp_path / "old.txt"
    report = _catenary(site, tmp_path, "report", "old-report", "3", "--set", "k=v", "-o", str(out))
    assert report.returncode == 0, report.stderr
    assert out.read_text() == "3 {'k': 'v'}"
