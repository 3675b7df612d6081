"""The GenTL backend: frame grabbers and cameras whose vendor ships a GenTL producer (``.cti``),
through harvesters (``backend = "gentl"``).

**Producers.** The producers are the settings' ``cti`` files (or those that
``GENICAM_GENTL64_PATH`` lists). One ``harvesters.core.Harvester`` per set of producers is
shared by every camera of this process that uses them: GenTL loads a producer once per process
(a second Harvester of the same file finds no devices), and ``Harvester.update`` closes every
camera opened through it. So the devices are discovered when the first camera opens, and that
list serves while any camera is open: a camera that drops off is reopened from it (with one
camera, or once every camera is closed, it is discovered afresh).

**Devices** are found by ``serial`` (the device's serial number) or ``device_id`` (its id in
the producer) and configured through the remote device's node map, by the same standard
feature names as every backend (:func:`catenary_camera.features.configure`); a value the
device refuses is one line. ``packet_size`` sets ``GevSCPSPacketSize``.

**Frames** come from ``ImageAcquirer.try_fetch`` as raw GenTL buffers, fetched by a thread
of the camera's own from the start of its acquisition (:class:`_Poller`), so that a frame's
host time is its arrival, whenever the stream reads it: GenTL gives no host time of arrival.
genicam holds Python's GIL while it waits for a buffer, which would starve the other threads
(the assembly, the writer), so the acquirer's own wait is 0 and the thread polls: it asks,
and sleeps :data:`POLL_INTERVAL_S` between asks (the host time is late by that much at most,
plus the scheduler's delay). A buffer is complete if GenTL says so, has no line padding and
holds the frame's bytes (harvesters itself drops a buffer GenTL marks incomplete: its lines
then show as a gap in the frame ids). Its bytes are copied out and the buffer goes straight
back to the producer; up to ``buffers`` frames wait for the stream, then the producer's
buffers fill. The frame id is GenTL's (16 bits wrapping, 1-65535, for GigE Vision devices
without extended ids; else never wrapping). The device's timestamp is used when the producer
gives one, else the host's time (as for an Aravis frame stamped 0): genicam's simulated
producer ``viky.cti`` gives none.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from catenary.errors import UserError, one_line

from .backend import GV_FRAME_ID_MODULUS, CameraUnavailable, Frame
from .features import Value, configure, set_first
from .pixels import buffer_bytes
from .settings import CameraSettings, GigeSettings

__all__ = ["GenTLCamera", "load_harvester"]

POLL_INTERVAL_S = 0.002  # a poller's sleep between two asks for a buffer [s]
POLL_WAIT_S = 1e-4  # how long one ask spins through the producer's (zero-wait) events [s]
PACKET_SIZE = ("GevSCPSPacketSize",)
EXTENDED_IDS = "GevGVSPExtendedIDMode"

_LOCK = threading.Lock()  # guards _HARVESTERS and every Harvester call
_HARVESTERS: dict[tuple[str, ...], tuple[Any, int]] = {}  # cti: (Harvester, cameras open)


def load_harvester() -> Any:
    """harvesters' ``Harvester`` class, or ``UserError`` saying what to install."""
    try:
        from harvesters.core import Harvester
    except ImportError as exc:
        raise UserError(
            "source 'gige' backend 'gentl' needs harvesters: pip install 'catenary[camera]' "
            f"({exc})"
        ) from None
    return Harvester


def _optional(module: Any, name: str) -> Any:
    """GenTL information ``name`` of ``module``, or None where the producer gives none."""
    from genicam.gentl import GenericException

    try:
        return getattr(module, name)
    except GenericException:
        return None


def _describe(info: Any) -> str:
    return f"{_optional(info, 'id_')} (serial {_optional(info, 'serial_number')})"


def _find(harvester: Any, camera: CameraSettings) -> Any:
    """The device information of ``camera`` among the producers' devices."""
    key, wanted = (
        ("id_", camera.device_id)
        if camera.device_id is not None
        else ("serial_number", camera.serial)
    )
    devices = list(harvester.device_info_list)
    found = [info for info in devices if _optional(info, key) == wanted]
    if len(found) > 1:
        raise UserError(
            f"camera {camera.device}: {len(found)} GenTL devices match "
            f"({', '.join(_describe(info) for info in found)}): name it by device_id"
        )
    if not found:
        listed = ", ".join(_describe(info) for info in devices) or "none"
        raise CameraUnavailable(
            f"camera {camera.device}: not among the GenTL producers' devices (found: {listed})"
        )
    return found[0]


def _check_producer(file: str) -> None:
    """``UserError`` in one line if ``file`` does not load as a GenTL producer (harvesters
    only logs that, and finds no devices)."""
    from genicam.gentl import GenericException, GenTLProducer

    producer = GenTLProducer.create_producer()
    try:
        producer.open(file)
    except GenericException as exc:
        raise UserError(
            f"source 'gige': setting cti = {file!r}: not a GenTL producer ({one_line(exc)})"
        ) from None
    producer.close()


def _open_acquirer(cti: tuple[str, ...], camera: CameraSettings) -> tuple[Any, str]:
    """Open ``camera`` through the shared Harvester of ``cti`` (module docstring): its
    ``ImageAcquirer`` and the device's transport layer type (``GEV``, ``CXP``, ...)."""
    with _LOCK:
        harvester, users = _HARVESTERS.get(cti, (None, 0))
        if harvester is None:
            for file in cti:
                _check_producer(file)
            harvester = load_harvester()()
            for file in cti:
                harvester.add_file(file)
            harvester.update()
        try:
            info = _find(harvester, camera)
            try:
                acquirer = harvester.create(info)
            except Exception as exc:  # genicam's errors: in use, access denied, gone
                problem = one_line(exc)
                raise CameraUnavailable(
                    f"camera {camera.device}: cannot open ({problem})"
                ) from None
        except (CameraUnavailable, UserError):
            if users == 0:
                harvester.reset()
            raise
        _HARVESTERS[cti] = (harvester, users + 1)
        return acquirer, str(_optional(info, "tl_type"))


def _close_acquirer(cti: tuple[str, ...], acquirer: Any) -> None:
    """Stop and release ``acquirer``; the Harvester too once no camera uses it."""
    with _LOCK:
        for release in (acquirer.stop, acquirer.destroy):
            with contextlib.suppress(Exception):  # genicam's errors: the device is gone already
                release()
        harvester, users = _HARVESTERS[cti]
        if users > 1:
            _HARVESTERS[cti] = (harvester, users - 1)
        else:
            del _HARVESTERS[cti]
            harvester.reset()


class _NodeMap:
    """A GenTL remote device's node map as a :class:`~catenary_camera.features.FeatureAccess`."""

    def __init__(self, node_map: Any, device: str) -> None:
        from genicam import genapi

        self._genapi = genapi
        self._map = node_map
        self._device = device

    def _node(self, name: str) -> Any:
        try:
            return self._map.get_node(name)
        except self._genapi.LogicalErrorException:  # no such node
            return None

    def _kind(self, node: Any) -> Any:
        return node.node.principal_interface_type

    def has(self, name: str) -> bool:
        node, genapi = self._node(name), self._genapi
        return (
            node is not None
            and bool(genapi.is_implemented(node.node))
            and bool(genapi.is_available(node.node))
        )

    def set(self, name: str, value: Value) -> None:
        node, kinds = self._node(name), self._genapi.EInterfaceType
        if not self._genapi.is_writable(node.node) and self.get(name) == value:
            return  # read-only and already so (a single-entry AcquisitionMode)
        kind = self._kind(node)
        typed: Value | bool = (
            float(value)
            if kind == kinds.intfIFloat
            else int(value)
            if kind == kinds.intfIInteger
            else bool(value)
            if kind == kinds.intfIBoolean
            else str(value)
        )
        try:
            node.value = typed
        except self._genapi.GenericException as exc:  # out of range, not writable
            raise UserError(
                f"camera {self._device}: {name} = {value!r} refused ({one_line(exc)})"
            ) from None

    def get(self, name: str) -> Value:
        node, kinds = self._node(name), self._genapi.EInterfaceType
        try:
            value = node.value
        except self._genapi.GenericException as exc:
            raise UserError(f"camera {self._device}: {name} unreadable ({one_line(exc)})") from None
        kind = self._kind(node)
        if kind == kinds.intfIFloat:
            return float(value)
        if kind in (kinds.intfIInteger, kinds.intfIBoolean):
            return int(value)
        return str(value)

    def entries(self, name: str) -> tuple[str, ...]:
        return tuple(self._node(name).symbolics)


class _Poller(threading.Thread):
    """Fetches a started acquirer's buffers as they arrive, stamps them with the host's time
    and queues their frames for :meth:`GenTLCamera.read` (module docstring). A failure is
    kept in ``error`` (``CameraUnavailable``, or ``UserError`` from ``to_frame``) and ends it."""

    def __init__(
        self, acquirer: Any, to_frame: Callable[[Any, float], Frame], size: int, device: str
    ) -> None:
        super().__init__(name=f"gentl-{device}", daemon=True)
        self._acquirer = acquirer
        self._to_frame = to_frame
        self._device = device
        self.frames: queue.Queue[Frame] = queue.Queue(maxsize=size)
        self.stopped = threading.Event()
        self.error: CameraUnavailable | UserError | None = None

    def run(self) -> None:
        try:
            while not self.stopped.is_set():
                buffer = self._acquirer.try_fetch(timeout=POLL_WAIT_S, is_raw=True)
                if buffer is None:
                    self.stopped.wait(POLL_INTERVAL_S)
                    continue
                frame = self._to_frame(buffer, time.time())
                buffer.parent.queue_buffer(buffer)
                while not self.stopped.is_set():
                    with contextlib.suppress(queue.Full):
                        self.frames.put(frame, timeout=POLL_INTERVAL_S)
                        break
        except UserError as exc:
            self.error = exc
        except Exception as exc:  # genicam's errors: the device or its stream is gone
            problem = one_line(exc)
            self.error = CameraUnavailable(f"camera {self._device}: connection lost ({problem})")


class GenTLCamera:
    """One rig camera through a GenTL producer (the
    :class:`~catenary_camera.backend.CameraBackend`; module docstring)."""

    frame_id_modulus: int | None = None  # known once connected

    def __init__(self, camera: CameraSettings, acquisition: GigeSettings) -> None:
        load_harvester()
        self._settings = camera
        self._acquisition = acquisition
        self._frame_bytes = buffer_bytes(
            camera.pixel_format, camera.width, acquisition.lines_per_frame
        )
        self._acquirer: Any = None
        self._poller: _Poller | None = None

    def connect(self) -> None:
        settings, cti = self._settings, self._acquisition.cti
        self.disconnect()
        acquirer, transport = _open_acquirer(cti, settings)
        self._acquirer = acquirer
        try:
            features = _NodeMap(acquirer.remote_device.node_map, settings.device)
            configure(features, settings, self._acquisition)
            if settings.packet_size is not None:
                set_first(
                    features, PACKET_SIZE, settings.packet_size, settings.device, "packet size"
                )
            extended = features.has(EXTENDED_IDS) and features.get(EXTENDED_IDS) == "On"
            self.frame_id_modulus = (
                GV_FRAME_ID_MODULUS if transport == "GEV" and not extended else None
            )
            acquirer.num_buffers = max(self._acquisition.buffers, acquirer.min_num_buffers)
            acquirer.timeout_period_on_update_event_data_call = 0  # poll (module docstring)
            acquirer.start()
        except UserError:
            self.disconnect()
            raise
        except Exception as exc:  # genicam's errors
            self.disconnect()
            problem = one_line(exc)
            raise CameraUnavailable(f"camera {settings.device}: cannot start ({problem})") from None
        size = self._acquisition.buffers
        self._poller = _Poller(acquirer, self._frame, size, settings.device)
        self._poller.start()

    def read(self, timeout_s: float) -> Frame | None:
        poller = self._poller
        if poller is None:
            raise CameraUnavailable(f"camera {self._settings.device}: not connected")
        try:
            return poller.frames.get(timeout=timeout_s)
        except queue.Empty:
            if poller.error is not None:
                raise poller.error from None
            return None

    def check(self) -> None:
        acquirer, poller = self._acquirer, self._poller
        if acquirer is None or poller is None:
            raise CameraUnavailable(f"camera {self._settings.device}: not connected")
        if poller.error is not None:
            raise poller.error
        try:
            acquirer.remote_device.node_map.Width.get_value(ignore_cache=True)
        except Exception as exc:  # genicam's errors: no answer
            device, problem = self._settings.device, one_line(exc)
            raise CameraUnavailable(f"camera {device}: no answer ({problem})") from None

    def _frame(self, buffer: Any, host_s: float) -> Frame:
        """The frame of a raw GenTL buffer that arrived at ``host_s`` [s, UNIX time]."""
        frame_id = _optional(buffer, "frame_id")
        if frame_id is None:
            raise UserError(
                f"camera {self._settings.device}: its GenTL producer gives no frame ids, which "
                "keep the cameras in step"
            )
        size = self._frame_bytes
        offset = _optional(buffer, "image_offset") or 0
        filled = _optional(buffer, "size_filled")
        data = None
        if (
            buffer.is_complete()
            and not _optional(buffer, "padding_x")
            and (filled is None or offset + size <= filled)
        ):
            data = bytes(memoryview(buffer.raw_buffer)[offset : offset + size])
            data = data if len(data) == size else None
        device_ns = _optional(buffer, "timestamp_ns")
        return Frame(
            frame_id=int(frame_id),
            complete=data is not None,
            device_time_s=device_ns * 1e-9 if device_ns else host_s,
            host_time_s=host_s,
            data=data,
            host_stamped=not device_ns,
        )

    def disconnect(self) -> None:
        poller, self._poller = self._poller, None
        if poller is not None:
            poller.stopped.set()
            poller.join()
        acquirer, self._acquirer = self._acquirer, None
        if acquirer is not None:
            _close_acquirer(self._acquisition.cti, acquirer)
