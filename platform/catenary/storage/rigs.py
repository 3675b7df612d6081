"""Vehicles and their rig calibrations in the database (versioned, stored verbatim)."""

from __future__ import annotations

import hashlib

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from catenary.domain import VehicleGeometry
from catenary.errors import UserError
from catenary.storage.inserts import get_or_add, insert_new
from catenary.storage.models import RigCalibration, Vehicle

GEOMETRY_TOLERANCE_MM = 1e-6


def register_vehicle(session: Session, geometry: VehicleGeometry) -> Vehicle:
    """The vehicle called ``geometry.name``, added if new.

    A vehicle already registered under that name with another geometry is refused (a
    ``UserError`` naming the field): runs measured with the old geometry must stay
    reproducible, so give the rebuilt vehicle a new name.
    """
    fields = ("roof_height_mm", "sensor_height_mm", "sensor_baseline_mm")
    vehicle = get_or_add(
        session,
        Vehicle,
        {"name": geometry.name},
        {field: getattr(geometry, field) for field in fields},
    )
    for field in fields:
        stored, given = getattr(vehicle, field), getattr(geometry, field)
        if abs(stored - given) > GEOMETRY_TOLERANCE_MM:
            raise UserError(
                f"vehicle {geometry.name!r} is registered with {field} = {stored}, "
                f"not {given}: give the changed vehicle a new name"
            )
    return vehicle


def register_rig_calibration(
    session: Session, geometry: VehicleGeometry, name: str, content_toml: str
) -> RigCalibration:
    """The stored rig calibration with this content, or a new version of ``name``.

    The same file content (by SHA-256) for the same vehicle is stored once; a changed file of
    the same name becomes the next version. A process storing the same calibration, or another
    version of it, at the same time is no error (``insert_new``).
    """
    vehicle = register_vehicle(session, geometry)
    digest = hashlib.sha256(content_toml.encode("utf-8")).hexdigest()
    while True:  # again when a process added this name's next version meanwhile
        existing = session.scalars(
            select(RigCalibration).where(
                RigCalibration.vehicle_id == vehicle.id, RigCalibration.sha256 == digest
            )
        ).first()
        if existing is not None:
            return existing
        latest = session.scalar(
            select(func.max(RigCalibration.version)).where(
                RigCalibration.vehicle_id == vehicle.id, RigCalibration.name == name
            )
        )
        row = {
            "vehicle_id": vehicle.id,
            "name": name,
            "version": (latest or 0) + 1,
            "content_toml": content_toml,
            "sha256": digest,
        }
        insert_new(session, RigCalibration, [row], ["vehicle_id", "name", "version"])


def latest_rig_calibration(session: Session, vehicle_id: int) -> RigCalibration:
    """The vehicle's rig calibration stored last (every stored vehicle has one)."""
    found = session.scalars(
        select(RigCalibration)
        .where(RigCalibration.vehicle_id == vehicle_id)
        .order_by(RigCalibration.created_at.desc(), RigCalibration.id.desc())
        .limit(1)
    ).first()
    if found is None:
        raise UserError(f"vehicle {vehicle_id} has no rig calibration stored: give --rig FILE")
    return found
