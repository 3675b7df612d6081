"""``catenary simulate``: writes run, truth, register (and captures); errors in one line."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from catenary.measurement.runfile import open_run
from catenary_linescan.commands import simulate


def test_simulate_writes_run_truth_register_and_captures(
    tmp_path: Path, small_rig_file: Path
) -> None:
    rig = small_rig_file
    out = tmp_path / "run.h5"
    result = CliRunner().invoke(
        simulate,
        [
            str(out),
            "--rig",
            str(rig),
            "--length-m",
            "6",
            "--scan-rate-hz",
            "200",
            "--lighting",
            "day-white",
            "--no-overlap",
            "--captures",
            str(tmp_path / "caps.h5"),
        ],
    )
    assert result.exit_code == 0, result.output
    for name in ("run.h5", "run.truth.h5", "run.masts.csv", "caps.h5", "caps.truth.h5"):
        assert (tmp_path / name).exists(), name
    with open_run(out) as run:
        assert run.header.camera_pixels["cam1"] == 512
    again = CliRunner().invoke(simulate, [str(out), "--rig", str(rig), "--length-m", "6"])
    assert again.exit_code != 0
    assert "already exists" in again.output and "Traceback" not in again.output


def test_bad_options_are_one_line_errors(tmp_path: Path, small_rig_file: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(simulate, [str(tmp_path / "a.h5"), "--rig", str(tmp_path / "no.toml")])
    assert result.exit_code != 0
    assert "no such rig file" in result.output
    assert len(result.output.strip().splitlines()) == 1
    rig = small_rig_file
    result = runner.invoke(
        simulate, [str(tmp_path / "a.h5"), "--rig", str(rig), "--sun-blind", "cam7"]
    )
    assert result.exit_code != 0 and "no camera 'cam7'" in result.output
    assert not (tmp_path / "a.h5").exists()
    result = runner.invoke(simulate, [str(tmp_path / "nodir" / "a.h5"), "--rig", str(rig)])
    assert result.exit_code != 0 and "no such directory" in result.output


def test_captures_into_a_missing_directory_fail_before_anything_is_written(
    tmp_path: Path, small_rig_file: Path
) -> None:
    rig = small_rig_file
    out = tmp_path / "run.h5"
    result = CliRunner().invoke(
        simulate,
        [str(out), "--rig", str(rig), "--length-m", "2", "--captures", str(tmp_path / "x/c.h5")],
    )
    assert result.exit_code != 0 and "no such directory" in result.output
    assert not out.exists()
