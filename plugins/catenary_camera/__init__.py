"""Live line-scan cameras: the ``gige`` scan source (GigE Vision through Aravis, or a vendor's
GenTL producer through harvesters: :mod:`catenary_camera.gentl`).

The optional extra ``camera`` (``pip install 'catenary[camera]'``: PyGObject, harvesters) with
Aravis's introspection data (Debian: ``gir1.2-aravis-0.8``) for backend ``aravis``, a GenTL
producer (``.cti``) for backend ``gentl``. ``catenary record OUT.h5 --source gige
--vehicle-source can ...`` records a run from the rig's cameras and the CAN bus. Settings:
:mod:`catenary_camera.settings`; how frames become scans: :mod:`catenary_camera.assembly`
and :mod:`catenary_camera.stream`. Modules are imported inside the hook's callable so that
``catenary --help`` works without the extra.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from catenary.plugins import hookimpl
from catenary.plugins.types import ScanStream, Source


def open_gige_source(settings: Mapping[str, Any]) -> ScanStream:
    """Open the ``gige`` source (settings: :mod:`catenary_camera.settings`)."""
    from catenary_camera.stream import open_gige

    return open_gige(settings)


@hookimpl
def catenary_sources() -> list[Source]:
    return [
        Source(
            "gige",
            "Line-scan cameras through Aravis (GigE Vision) or a GenTL producer (the optional "
            "extra 'camera')",
            open_gige_source,
        )
    ]
