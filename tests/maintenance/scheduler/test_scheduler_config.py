"""``[scheduler]``: jobs declared in the config, every mistake one line naming file, job, key."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from apscheduler.triggers.cron import CronTrigger
from apscheduler.triggers.interval import IntervalTrigger

from catenary.config import load_settings
from catenary.errors import UserError
from catenary.maintenance.jobs import output_path
from catenary.maintenance.notifications import notification_config
from catenary.maintenance.scheduler import scheduler_config


def settings_with(tmp_path: Path, text: str) -> Any:
    path = tmp_path / "catenary.toml"
    path.write_text(text)
    return load_settings(config_path=path)


def test_a_full_config(tmp_path: Path) -> None:
    settings = settings_with(
        tmp_path,
        """
[scheduler]
timezone = "Europe/Berlin"
misfire_grace_minutes = 90

[[scheduler.jobs]]
id = "alerts"
job = "evaluate-alerts"
cron = "30 5 * * *"

[[scheduler.jobs]]
id = "deliver"
job = "deliver-notifications"
interval_minutes = 15

[[scheduler.jobs]]
id = "weekly"
job = "report"
cron = "0 6 * * 1"
reporter = "maintenance"
line = "L1"
output = "/srv/reports/{line}-{date}.html"
options = { horizon_days = "180" }
""",
    )
    config = scheduler_config(settings)
    assert config.timezone.key == "Europe/Berlin"
    assert config.misfire_grace_minutes == 90
    alerts, deliver, weekly = config.jobs
    assert (alerts.id, alerts.job, alerts.cron, alerts.options) == (
        "alerts",
        "evaluate-alerts",
        "30 5 * * *",
        {},
    )
    assert (deliver.interval_minutes, deliver.cron) == (15, None)
    assert weekly.options == {
        "reporter": "maintenance",
        "line": "L1",
        "output": "/srv/reports/{line}-{date}.html",
        "options": {"horizon_days": "180"},
    }
    assert weekly.description(config.timezone) == "report at cron '0 6 * * 1' (Europe/Berlin)"
    assert deliver.description(config.timezone) == "deliver-notifications every 15 min"
    trigger = weekly.trigger(config.timezone)
    assert isinstance(trigger, CronTrigger)
    assert str(trigger.timezone) == "Europe/Berlin"
    assert isinstance(deliver.trigger(config.timezone), IntervalTrigger)


def test_defaults(tmp_path: Path) -> None:
    config = scheduler_config(settings_with(tmp_path, ""))
    assert (config.timezone.key, config.misfire_grace_minutes, config.jobs) == ("UTC", 360, ())
    assert (config.lease.lease_s, config.lease.heartbeat_s) == (30, 10)


def test_the_heartbeat_is_a_third_of_the_lease_unless_given(tmp_path: Path) -> None:
    config = scheduler_config(settings_with(tmp_path, "[scheduler]\nlease_seconds = 6"))
    assert (config.lease.lease_s, config.lease.heartbeat_s) == (6, 2)
    text = "[scheduler]\nlease_seconds = 45\nheartbeat_seconds = 0.1"
    config = scheduler_config(settings_with(tmp_path, text))
    assert (config.lease.lease_s, config.lease.heartbeat_s) == (45, 0.1)


def test_report_output_paths(tmp_path: Path) -> None:
    data = tmp_path / "data"
    assert output_path("r/{line}-{date}.html", line="L1", date="2024-05-06", data_dir=data) == (
        data / "r" / "L1-2024-05-06.html"
    )
    assert output_path("/srv/{date}.csv", line=None, date="2024-05-06", data_dir=data) == (
        Path("/srv/2024-05-06.csv")
    )


JOB = '[[scheduler.jobs]]\nid = "j"\n'


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "[scheduler]\ntz = 'UTC'",
            "unknown key scheduler.tz (known: heartbeat_seconds, jobs, lease_seconds, ",
        ),
        ("[scheduler]\ntimezone = 'Mars/Olympus'", "scheduler.timezone: unknown time zone 'Mars/"),
        ("[scheduler]\nmisfire_grace_minutes = 0", "scheduler.misfire_grace_minutes must be a "),
        ("[scheduler]\njobs = 3", "scheduler.jobs must be an array of tables"),
        (
            "[scheduler]\nlease_seconds = 60",
            "scheduler.lease_seconds must be a number from 1 to 45, not 60",
        ),
        (
            "[scheduler]\nlease_seconds = '30'",
            "scheduler.lease_seconds must be a number from 1 to 45, not '30'",
        ),
        (
            "[scheduler]\nlease_seconds = 6\nheartbeat_seconds = 3",
            "scheduler.heartbeat_seconds (lease_seconds / 3 at most) must be a number from 0.1 "
            "to 2, not 3",
        ),
        (
            "[scheduler]\nheartbeat_seconds = 0",
            "scheduler.heartbeat_seconds (lease_seconds / 3 at most) must be a number from 0.1 "
            "to 10, not 0",
        ),
        (
            "[[scheduler.jobs]]\njob = 'report'",
            "scheduler.jobs[1].id must be a string of 1 to 191 characters, not None",
        ),
        (
            JOB + "job = 'backup'\ncron = '0 * * * *'",
            "scheduler job 'j': unknown job 'backup' (known: ",
        ),
        (JOB + "job = 'evaluate-alerts'", "scheduler job 'j': give cron or interval_minutes"),
        (
            JOB + "job = 'evaluate-alerts'\ncron = '0 * * * *'\ninterval_minutes = 5",
            "scheduler job 'j': give cron or interval_minutes (one of them)",
        ),
        (
            JOB + "job = 'evaluate-alerts'\ncron = '0 6 * *'",
            "scheduler job 'j': invalid cron '0 6 * *': Wrong number of fields",
        ),
        (
            JOB + "job = 'evaluate-alerts'\ncron = '0 25 * * *'",
            "scheduler job 'j': invalid cron '0 25 * * *': ",
        ),
        (
            JOB + "job = 'evaluate-alerts'\ninterval_minutes = -5",
            "scheduler job 'j': interval_minutes must be a positive number, not -5",
        ),
        (
            JOB + "job = 'evaluate-alerts'\ninterval_minutes = 5\nline = 'L1'",
            "scheduler job 'j': unknown key line (evaluate-alerts jobs take no options)",
        ),
        (
            JOB + "job = 'report'\ninterval_minutes = 5\noutput = 'x.html'",
            "scheduler job 'j': report jobs need reporter",
        ),
        (
            JOB + "job = 'report'\ncron = '0 6 * * 1'\nreporter = 'r'\noutput = '{site}.html'",
            "scheduler job 'j': output '{site}.html' has a bad placeholder (KeyError: 'site'; "
            "known: {date}, {line})",
        ),
        (
            JOB + "job = 'report'\ncron = '0 6 * * 1'\nreporter = 'r'\noutput = 'x'\nrepotr = 1",
            "scheduler job 'j': unknown key repotr (known for report jobs: line, options, ",
        ),
        (
            JOB + "job = 'report'\ncron = '0 6 * * 1'\nreporter = 'r'\noutput = 'x'\nruns = 3",
            "scheduler job 'j': runs must be a list of run ids or 'latest', not 3",
        ),
        (
            (JOB + "job = 'evaluate-alerts'\ncron = '0 6 * * 1'\n") * 2,
            "two scheduler jobs have the id 'j'",
        ),
    ],
)
def test_mistakes_are_one_line(tmp_path: Path, text: str, message: str) -> None:
    settings = settings_with(tmp_path, text)
    with pytest.raises(UserError) as raised:
        scheduler_config(settings)
    error = str(raised.value)
    assert error.startswith(f"{settings.config_path}: ")
    assert message in error
    assert "\n" not in error


DEPLOY = Path(__file__).parents[3] / "deploy"


def test_the_deploy_sample_config_is_valid() -> None:
    settings = load_settings(config_path=DEPLOY / "catenary.toml")
    assert [job.job for job in scheduler_config(settings).jobs] == [
        "evaluate-alerts",
        "deliver-notifications",
        "report",
    ]
    channels = notification_config(settings).channels
    assert [channel.notifier for channel in channels] == ["email", "webhook"]


def test_the_unit_file_runs_the_service() -> None:
    lines = (DEPLOY / "catenary-scheduler.service").read_text().splitlines()
    for line in (
        "ExecStart=/opt/catenary/.venv/bin/catenary scheduler",
        "Environment=CATENARY_CONFIG=/etc/catenary/catenary.toml",
        "Restart=on-failure",
        "KillSignal=SIGTERM",
        "User=catenary",
        "After=postgresql.service network-online.target",
    ):
        assert line in lines
