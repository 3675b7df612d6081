"""A third party's wire type: XW-95, a made-up 95 mm² round grooved profile."""

from __future__ import annotations

from catenary.plugins import hookimpl
from catenary.wiretype import WireType


@hookimpl
def catenary_wire_types() -> list[WireType]:
    return [
        WireType(
            name="XW-95",
            standard="Example Works XW",
            height_mm=11.2,
            width_mm=11.2,
            area_mm2=95.0,
            nominal_area_mm2=95.0,
            source="test fixture (tests/wiretypes/thirdparty)",
        )
    ]
