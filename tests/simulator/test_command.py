"""``catenary simulate``: writes run, truth, register (and captures); errors in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
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


def test_a_region_of_interest_records_the_sensor_pixels_it_names(
    tmp_path: Path, small_rig_file: Path
) -> None:
    common = [
        "--rig", str(small_rig_file), "--length-m", "3", "--scan-rate-hz", "200",
        "--no-overlap", "--seed", "4",
    ]  # fmt: skip
    full, cut = tmp_path / "full.h5", tmp_path / "cut.h5"
    assert CliRunner().invoke(simulate, [str(full), *common]).exit_code == 0
    result = CliRunner().invoke(
        simulate, [str(cut), *common, "--roi", "cam2=100:300", "--roi", "cam4=0:512"]
    )
    assert result.exit_code == 0, result.output
    with open_run(full) as a, open_run(cut) as b:
        assert b.header.camera_offset_px == {"cam2": 100, "cam4": 0}
        assert b.header.camera_pixels == {"cam1": 512, "cam2": 300, "cam3": 512, "cam4": 512}
        (whole,) = a.blocks(10_000)
        (part,) = b.blocks(10_000)
    np.testing.assert_array_equal(
        part.cameras["cam2"].lines, whole.cameras["cam2"].lines[:, 100:400]
    )
    np.testing.assert_array_equal(part.cameras["cam1"].lines, whole.cameras["cam1"].lines)


@pytest.mark.parametrize(
    ("roi", "needle"),
    [
        ("cam2=400:200", "offset_px 400 and width 200 do not lie within its 512 pixels"),
        ("cam9=0:100", "no camera 'cam9'"),
        ("cam2=10", "--roi 'cam2=10': expected CAMERA=OFFSET:WIDTH"),
        ("cam2=-1:100", "--roi 'cam2=-1:100'"),
    ],
)
def test_a_bad_region_of_interest_is_a_one_line_error(
    tmp_path: Path, small_rig_file: Path, roi: str, needle: str
) -> None:
    out = tmp_path / "a.h5"
    result = CliRunner().invoke(simulate, [str(out), "--rig", str(small_rig_file), "--roi", roi])
    assert result.exit_code != 0
    assert needle in result.output and len(result.output.strip().splitlines()) == 1
    assert not out.exists()
