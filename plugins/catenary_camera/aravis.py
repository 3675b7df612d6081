"""The Aravis backend: GigE Vision cameras through Aravis 0.8 and PyGObject.

A camera is opened by address (``Aravis.Camera.new``, which also takes a host name) or by
serial number (found among the devices Aravis discovers). Features are set through
:func:`catenary_camera.features.configure` with Aravis's range checks on, so a value the
camera's GenICam description refuses is one line; the stream packet size through Aravis's
GigE Vision call. Frames come from ``ArvStream.timeout_pop_buffer`` (which waits without
holding Python's GIL) and their buffer goes straight back to the stream.

A lost connection is noticed by the reader waiting too long for a frame
(:mod:`catenary_camera.stream`), which then disconnects and reconnects; with encoder
triggering, while the train stands, by ``check`` (a read of ``Width``, the register cache
off, so that it asks the camera). The device's
``control-lost`` signal (Aravis's heartbeat) is not used: it runs its Python handler in the
heartbeat's own thread, whose wrapper of the device then held the last reference when the
reader had let the camera go, so that the device was finalised in that thread, which cannot
join itself (GLib-ERROR "Resource deadlock avoided" in ``g_system_thread_wait``: the
recording process aborted, once in 26 reconnections under load).

Frame ids are GigE Vision 1.x's 16 bits (1-65535, wrapping); extended 64-bit ids (GigE
Vision 2, ``GevGVSPExtendedIDMode``) are not enabled by this backend.
"""

from __future__ import annotations

import contextlib
from typing import Any

from catenary.errors import UserError, one_line

from .backend import GV_FRAME_ID_MODULUS, CameraUnavailable, Frame
from .features import Value, configure
from .settings import CameraSettings, GigeSettings

__all__ = ["AravisCamera", "load_aravis"]


def load_aravis() -> Any:
    """The ``Aravis`` 0.8 module of PyGObject, or ``UserError`` saying what to install."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError) as exc:
        raise UserError(
            "source 'gige' needs Aravis 0.8 through PyGObject: pip install 'catenary[camera]' "
            f"and Aravis's introspection data (Debian: gir1.2-aravis-0.8) ({exc})"
        ) from None
    return Aravis


class _Features:
    """Aravis's camera as a :class:`~catenary_camera.features.FeatureAccess`."""

    def __init__(self, aravis: Any, camera: Any, device: str) -> None:
        self._aravis = aravis
        self._camera = camera
        self._device = device

    def _node(self, name: str) -> Any:
        return self._camera.get_device().get_feature(name)

    def has(self, name: str) -> bool:
        try:
            return bool(self._camera.is_feature_available(name))
        except Exception:  # GLib.Error: a feature whose availability cannot be read
            return False

    def set(self, name: str, value: Value) -> None:
        aravis, camera, node = self._aravis, self._camera, self._node(name)
        try:
            if isinstance(node, aravis.GcEnumeration) or isinstance(value, str):
                camera.set_string(name, str(value))
            elif isinstance(node, aravis.GcFloat):
                camera.set_float(name, float(value))
            elif isinstance(node, aravis.GcBoolean):
                camera.set_boolean(name, bool(value))
            else:
                camera.set_integer(name, int(value))
        except Exception as exc:  # GLib.Error: out of range, not writable, no answer
            problem = one_line(exc)
            raise UserError(
                f"camera {self._device}: {name} = {value!r} refused ({problem})"
            ) from None

    def get(self, name: str) -> Value:
        aravis, camera, node = self._aravis, self._camera, self._node(name)
        if isinstance(node, aravis.GcEnumeration):
            return str(camera.get_string(name))
        if isinstance(node, aravis.GcFloat):
            return float(camera.get_float(name))
        if isinstance(node, aravis.GcBoolean):
            return int(camera.get_boolean(name))
        return int(camera.get_integer(name))

    def entries(self, name: str) -> tuple[str, ...]:
        return tuple(self._camera.dup_available_enumerations_as_strings(name))


class AravisCamera:
    """One rig camera through Aravis (the :class:`~catenary_camera.backend.CameraBackend`)."""

    frame_id_modulus: int | None = GV_FRAME_ID_MODULUS

    def __init__(self, camera: CameraSettings, acquisition: GigeSettings) -> None:
        self._aravis = load_aravis()
        self._settings = camera
        self._acquisition = acquisition
        self._camera: Any = None
        self._stream: Any = None

    def _device_id(self) -> str:
        aravis, settings = self._aravis, self._settings
        if settings.address is not None:
            return settings.address
        aravis.update_device_list()
        for index in range(aravis.get_n_devices()):
            if aravis.get_device_serial_nbr(index) == settings.serial:
                return str(aravis.get_device_id(index))
        raise CameraUnavailable(f"camera {settings.device}: not found")

    def connect(self) -> None:
        aravis, settings = self._aravis, self._settings
        self.disconnect()
        try:
            camera = aravis.Camera.new(self._device_id())
        except CameraUnavailable:
            raise
        except Exception as exc:  # GLib.Error: not found, no answer
            problem = one_line(exc)
            raise CameraUnavailable(f"camera {settings.device}: cannot open ({problem})") from None
        self._camera = camera
        camera.set_range_check_policy(aravis.RangeCheckPolicy.ENABLE)
        camera.get_device().set_register_cache_policy(aravis.RegisterCachePolicy.DISABLE)
        try:
            configure(_Features(aravis, camera, settings.device), settings, self._acquisition)
            if settings.packet_size is not None:
                camera.gv_set_packet_size(settings.packet_size)
            stream = camera.create_stream(None, None)
            payload = camera.get_payload()
            for _ in range(self._acquisition.buffers):
                stream.push_buffer(aravis.Buffer.new_allocate(payload))
            camera.start_acquisition()
        except UserError:
            self.disconnect()
            raise
        except Exception as exc:  # GLib.Error
            self.disconnect()
            problem = one_line(exc)
            raise CameraUnavailable(f"camera {settings.device}: cannot start ({problem})") from None
        self._stream = stream

    def read(self, timeout_s: float) -> Frame | None:
        if self._stream is None:
            raise CameraUnavailable(f"camera {self._settings.device}: connection lost")
        buffer = self._stream.timeout_pop_buffer(max(int(timeout_s * 1e6), 1))
        if buffer is None:
            return None
        try:
            complete = buffer.get_status() == self._aravis.BufferStatus.SUCCESS
            host_s = buffer.get_system_timestamp() * 1e-9
            device_ns = buffer.get_timestamp()
            return Frame(
                frame_id=int(buffer.get_frame_id()),
                complete=complete,
                device_time_s=device_ns * 1e-9 if device_ns else host_s,
                host_time_s=host_s,
                data=bytes(buffer.get_data()) if complete else None,
                host_stamped=not device_ns,
            )
        finally:
            self._stream.push_buffer(buffer)

    def check(self) -> None:
        if self._camera is None:
            raise CameraUnavailable(f"camera {self._settings.device}: not connected")
        try:  # no register cache (connect): this asks the camera
            self._camera.get_integer("Width")
        except Exception as exc:  # GLib.Error: no answer
            device, problem = self._settings.device, one_line(exc)
            raise CameraUnavailable(f"camera {device}: no answer ({problem})") from None

    def disconnect(self) -> None:
        camera, self._camera, self._stream = self._camera, None, None
        if camera is not None:
            with contextlib.suppress(Exception):  # GLib.Error: the camera is gone already
                camera.stop_acquisition()
