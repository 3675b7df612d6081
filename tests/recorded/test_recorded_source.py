from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from catenary.errors import FormatError, UserError
from catenary.measurement.runfile import RunFileWriter
from catenary.plugins import PluginRegistry


def test_recorded_source_streams_a_run_file(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    lines = np.arange(10 * 8, dtype=np.uint8).reshape(10, 8)
    with RunFileWriter(path, scan_rate_hz=1000.0, cameras={"a": (8, 8), "b": (8, 8)}) as writer:
        writer.append(np.arange(10) * 0.01, np.arange(10) * 0.001, {"a": lines, "b": lines})
        writer.append_vehicle(np.array([0.0, 0.01]), np.zeros(2), np.zeros(2), np.zeros(2))
    source = PluginRegistry().sources()["recorded"]
    stream = source.open({"path": str(path)})
    try:
        assert stream.header.scans == 10
        blocks = list(stream.blocks(4))
    finally:
        stream.close()
    assert [b.scans for b in blocks] == [4, 4, 2]
    np.testing.assert_array_equal(np.concatenate([b.cameras["a"].lines for b in blocks]), lines)


def test_recorded_source_refuses_missing_path_and_bad_file(tmp_path: Path) -> None:
    source = PluginRegistry().sources()["recorded"]
    with pytest.raises(UserError, match="setting 'path'"):
        source.open({})
    bad = tmp_path / "notes.h5"
    bad.write_text("not hdf5")
    with pytest.raises(FormatError, match=r"notes\.h5"):
        source.open({"path": str(bad)})
