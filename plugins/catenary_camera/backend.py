"""What the ``gige`` source needs of a camera backend: Aravis (:mod:`catenary_camera.aravis`)
or a GenTL producer through harvesters (:mod:`catenary_camera.gentl`).

A backend opens one rig camera, configures it from the same settings
(:mod:`catenary_camera.settings`, through :mod:`catenary_camera.features`), starts its
acquisition and hands out its frames one by one; the stream (:mod:`catenary_camera.stream`)
does the rest (clocks, assembly, reconnection) the same way for every backend.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

__all__ = ["GV_FRAME_ID_MODULUS", "CameraBackend", "CameraUnavailable", "Frame"]

GV_FRAME_ID_MODULUS = 65535  # GigE Vision 1.x's 16-bit frame (block) ids run 1-65535


class CameraUnavailable(Exception):
    """The camera cannot be reached now (not found, connection lost): worth retrying."""


@dataclass(frozen=True)
class Frame:
    """One frame as the camera delivered it.

    ``complete``: every packet arrived (else ``data`` is None: its lines are invalid).
    ``device_time_s`` is the camera's timestamp of the frame [s, the camera's clock];
    ``host_time_s`` the host's UNIX time when it started arriving [s]. ``host_stamped``: the
    frame carries no timestamp of the camera's, and ``device_time_s`` is ``host_time_s``,
    which says when the frame arrived, not when its lines were taken.
    """

    frame_id: int
    complete: bool
    device_time_s: float
    host_time_s: float
    data: bytes | None
    host_stamped: bool = False


class CameraBackend(Protocol):
    """One rig camera (module docstring). Not thread-safe: one reader thread uses it."""

    frame_id_modulus: int | None  # frame ids run 1 .. modulus and wrap; None: never wrap

    def connect(self) -> None:
        """Open the device, configure it and start acquiring. ``CameraUnavailable`` if it
        cannot be reached, ``UserError`` if it refuses a setting."""
        ...

    def read(self, timeout_s: float) -> Frame | None:
        """The next frame, or None if none came within ``timeout_s``. ``CameraUnavailable``
        when the connection is lost."""
        ...

    def check(self) -> None:
        """Read a register of the camera's, not a frame (its ``Width``, past any cache):
        ``CameraUnavailable`` if it does not answer. With encoder triggering, a camera that
        sends no frame may be standing with the train."""
        ...

    def disconnect(self) -> None:
        """Stop acquiring and release the device (safe to call twice or unconnected)."""
        ...
