"""Configurations, options and geometry a user can get wrong, through the real CLI: each is
refused in one line naming the file, section, key or option and what is allowed, before
anything is written (issue 15: unknown config sections, notifier settings found only at send
time, report options without bounds, a roof below the sensors, a run that did not move)."""

from __future__ import annotations

from pathlib import Path

import h5py
import pytest
import tomli_w

from catenary_linescan.simulator import DEMO_RIG_PATH

from .conftest import assert_refused, assert_succeeded, catenary

CAPTURES = DEMO_RIG_PATH.with_name("demo-captures.h5")


def write_config(path: Path, document: dict[str, object]) -> Path:
    path.write_text(tomli_w.dumps(document))
    return path


def sqlite_files(folder: Path) -> list[Path]:
    return sorted(folder.rglob("*.sqlite"))


# -- item 12: strict configuration -------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "words"),
    [
        (
            '[databse]\nurl = "sqlite:///typo.sqlite"\n',
            ["site.toml", "unknown section [databse]", "did you mean [database]?"],
        ),
        ('url = "sqlite:///x.sqlite"\n', ["unknown top-level key 'url'", "[database]"]),
    ],
)
def test_an_unknown_section_or_key_is_refused_and_no_database_is_made(
    tmp_path: Path, isolated_environment: Path, text: str, words: list[str]
) -> None:
    config = tmp_path / "site.toml"
    config.write_text(text)
    assert_refused(catenary("--config", config, "alerts", "list", cwd=tmp_path), *words)
    assert sqlite_files(tmp_path) == []


def test_plugins_are_still_listed_beside_an_unknown_section(tmp_path: Path) -> None:
    """To find the plugin that should declare the section, ``catenary plugins`` works."""
    config = write_config(tmp_path / "site.toml", {"camera": {"exposure_us": 100}})
    assert_succeeded(catenary("--config", config, "plugins"))


@pytest.mark.parametrize(
    "command",
    [
        ["alerts", "list"],
        ["notify", "status"],
        ["export", "latest", "--what", "spans", "-o", "x.csv"],
    ],
)
def test_a_read_only_command_does_not_create_a_missing_sqlite_file(
    tmp_path: Path, command: list[str]
) -> None:
    file = tmp_path / "data" / "fleet.sqlite"
    result = catenary("--db", f"sqlite:///{file}", *command, cwd=tmp_path)
    assert_refused(result, "fleet.sqlite does not exist", "run 'catenary db upgrade'")
    assert not file.exists()


# -- notifier settings, checked when a command starts ----------------------------------------


@pytest.fixture
def database(tmp_path: Path) -> str:
    url = f"sqlite:///{tmp_path / 'catenary.sqlite'}"
    assert_succeeded(catenary("--db", url, "db", "upgrade"))
    return url


def channel_config(folder: Path, notifier: str, settings: dict[str, object]) -> Path:
    channel = {"name": "ops", "notifier": notifier, "settings": settings}
    return write_config(
        folder / "site.toml",
        {"limits": {"policy": "db-ril-997"}, "notifications": {"channels": [channel]}},
    )


def test_a_wrong_notification_channel_is_refused_when_a_command_starts(
    tmp_path: Path, database: str
) -> None:
    """Every command that may queue or send notifications; ``notify status`` lists them."""
    config = channel_config(tmp_path, "webhook", {"url": "file:///etc/passwd"})
    run = tmp_path / "run.h5"
    run.write_bytes(b"not read: the channel is refused first")
    for command in (
        ["notify", "deliver"],
        ["notify", "requeue"],
        ["process", run, "--rig", run],
        ["scheduler"],
    ):
        result = catenary("--config", config, "--db", database, *command, timeout=60)
        words = ["site.toml", "notification channel 'ops'", "url must be an http(s) URL"]
        assert_refused(result, *words, "'file://'")
    assert_succeeded(catenary("--config", config, "--db", database, "notify", "status"))


@pytest.mark.parametrize(
    ("notifier", "settings", "words"),
    [
        ("webhook", {"url": "http://127.0.0.1:http/"}, ["url has a port that is not 1-65535"]),
        ("email", {"host": "smtp", "port": "25", "from": "a@b", "to": ["c@d"]}, ["port", "'25'"]),
        ("email", {"port": 25, "from": "a@b", "to": ["c@d"]}, ["host must be a non-empty string"]),
    ],
)
def test_a_wrong_channel_setting_is_one_line_naming_channel_and_key(
    tmp_path: Path, database: str, notifier: str, settings: dict[str, object], words: list[str]
) -> None:
    config = channel_config(tmp_path, notifier, settings)
    result = catenary("--config", config, "--db", database, "notify", "deliver")
    assert_refused(result, "site.toml", "notification channel 'ops'", *words)


def test_requeue_refuses_a_channel_that_is_not_configured(tmp_path: Path, database: str) -> None:
    channel = {"name": "ops", "notifier": "webhook", "settings": {"url": "http://127.0.0.1:9/"}}
    config = write_config(tmp_path / "site.toml", {"notifications": {"channels": [channel]}})
    result = catenary(
        "--config", config, "--db", database, "notify", "requeue", "--channel", "opss"
    )
    assert_refused(result, "--channel opss", "no such notification channel", "did you mean ops?")
    result = catenary("--config", config, "--db", database, "notify", "requeue")
    assert_succeeded(result)
    assert result.stdout == "0 failed notification(s) queued again\n"


# -- report options --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (
            ["run", "1", "--set", "segment_m=0.01"],
            ["segment_m", "'0.01'", "outside 50 to 1000000 m"],
        ),
        (["repeatability", "1", "2", "--set", "bin_mm=1e-9"], ["bin_mm", "outside 0.001 to 1 mm"]),
        (["repeatability", "1", "2", "--set", "max_shift_m=500"], ["max_shift_m", "0 to 10 m"]),
    ],
)
def test_a_report_option_out_of_bounds_is_refused_before_any_work(
    tmp_path: Path, args: list[str], words: list[str]
) -> None:
    """Refused before the database is even opened (this one does not exist)."""
    out = tmp_path / "report.html"
    database = f"sqlite:///{tmp_path / 'none.sqlite'}"
    assert_refused(catenary("--db", database, "report", *args, "-o", out), *words)
    assert not out.exists()


# -- geometry ------------------------------------------------------------------------------


def test_calibrate_refuses_a_roof_below_the_sensors(tmp_path: Path) -> None:
    vehicle = tmp_path / "vehicle.toml"
    vehicle.write_text(
        'name = "low"\nroof_height_mm = 900.0\nsensor_height_mm = 1100.0\n'
        "sensor_baseline_mm = 1800.0\n"
    )
    rig = tmp_path / "rig.toml"
    result = catenary("calibrate", CAPTURES, "--vehicle", vehicle, "-o", rig)
    assert_refused(
        result, "vehicle.toml", "roof_height_mm = 900.0 is not above sensor_height_mm = 1100.0"
    )
    assert not rig.exists()


# -- a run that did not move -------------------------------------------------------------------


@pytest.mark.slow  # simulates, calibrates and processes
def test_a_run_where_the_vehicle_did_not_move_is_refused_and_nothing_is_kept(
    tmp_path: Path, isolated_environment: Path, database: str
) -> None:
    run, rig = tmp_path / "run.h5", tmp_path / "rig.toml"
    assert_succeeded(catenary("simulate", run, "--length-m", "30", "--no-overlap"))
    assert_succeeded(catenary("calibrate", CAPTURES, "--vehicle", DEMO_RIG_PATH, "-o", rig))
    with h5py.File(run, "r+") as f:  # the encoder never advanced
        f["/scans/position_m"][:] = 0.0
    process = [
        "--db",
        database,
        "process",
        run,
        "--rig",
        rig,
        "--masts",
        run.with_suffix(".masts.csv"),
    ]
    result = catenary(*process)
    assert_refused(result, f"run {run} covers 0.0 m: the vehicle did not move", "nothing stored")
    samples = isolated_environment / "samples"
    assert not samples.exists() or not any(samples.iterdir())
    assert_refused(
        catenary("--db", database, "export", "latest", "--what", "spans", "-o", tmp_path / "s.csv"),
        "no run",
    )
