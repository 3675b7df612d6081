"""A small simulated run and its rig, for the robustness tests that run ``catenary process``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from click.testing import CliRunner

from catenary.cli import cli
from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig, record_run
from catenary_linescan.simulator.captures import write_captures


@dataclass(frozen=True)
class SmallRun:
    run: Path
    masts: Path
    rig: Path

    def process_args(self, database_url: str) -> list[str]:
        """``catenary`` arguments that process this run into ``database_url``."""
        return [
            "process", str(self.run), "--rig", str(self.rig), "--masts", str(self.masts),
            "--db", database_url,
        ]  # fmt: skip


def make_small_run(folder: Path) -> SmallRun:
    """A 60 m run at 160 km/h (1,363 scans; ``process`` takes a few seconds) in ``folder``."""
    run = folder / "run.h5"
    record_run(run, {"length_m": 60.0, "speed_kmh": 160.0, "seed": 3})
    captures, _ = write_captures(folder / "captures.h5", load_rig(DEMO_RIG_PATH), seed=2)
    rig = folder / "rig.toml"
    result = CliRunner().invoke(
        cli, ["calibrate", str(captures), "--vehicle", str(DEMO_RIG_PATH), "-o", str(rig)]
    )
    assert result.exit_code == 0, result.output
    return SmallRun(run, run.with_suffix(".masts.csv"), rig)
