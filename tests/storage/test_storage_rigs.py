from __future__ import annotations

import pytest
from sqlalchemy import Engine, select

from catenary.domain import VehicleGeometry
from catenary.errors import UserError
from catenary.storage.database import session_scope
from catenary.storage.models import RigCalibration, Vehicle
from catenary.storage.rigs import register_rig_calibration

GEOMETRY = VehicleGeometry("inspection-car-1", 3900.0, 1100.0, 1800.0)


def test_same_content_is_stored_once_and_changes_get_versions(migrated: Engine) -> None:
    with session_scope(migrated) as session:
        first = register_rig_calibration(session, GEOMETRY, "roof-rig", "a = 1\n")
        again = register_rig_calibration(session, GEOMETRY, "roof-rig", "a = 1\n")
        changed = register_rig_calibration(session, GEOMETRY, "roof-rig", "a = 2\n")
        assert again.id == first.id
        assert (first.version, changed.version) == (1, 2)
    with session_scope(migrated) as session:
        assert len(session.scalars(select(Vehicle)).all()) == 1
        assert len(session.scalars(select(RigCalibration)).all()) == 2


def test_a_vehicle_name_keeps_its_geometry(migrated: Engine) -> None:
    with session_scope(migrated) as session:
        register_rig_calibration(session, GEOMETRY, "roof-rig", "a = 1\n")
    moved = VehicleGeometry(GEOMETRY.name, 3950.0, 1100.0, 1800.0)
    with (
        pytest.raises(UserError, match=r"roof_height_mm = 3900\.0, not 3950\.0"),
        session_scope(migrated) as session,
    ):
        register_rig_calibration(session, moved, "roof-rig", "a = 3\n")
    with session_scope(migrated) as session:
        assert len(session.scalars(select(RigCalibration)).all()) == 1
