"""Recorded run files (HDF5, FORMATS.md) as an acquisition source.

Settings: ``path`` (the run file). The file is checked on open and streamed in blocks with the
vehicle sensors interpolated to the scan times (``catenary.measurement.runfile``).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from catenary.errors import UserError
from catenary.plugins import hookimpl
from catenary.plugins.types import Source

if TYPE_CHECKING:
    from catenary.measurement.runfile import RunFile


def open_recorded(settings: Mapping[str, Any]) -> RunFile:
    """Open the run file named by ``settings["path"]``."""
    from catenary.measurement.runfile import open_run

    path = settings.get("path")
    if not isinstance(path, str | Path) or not str(path):
        raise UserError(f"source 'recorded': setting 'path' must name a run file, not {path!r}")
    return open_run(path)


@hookimpl
def catenary_sources() -> list[Source]:
    return [Source("recorded", "Recorded run file (HDF5, FORMATS.md layout)", open_recorded)]
