"""Calibration captures: the files (FORMATS.md) and the targets measured in them.

The resolution calibration tool of the paper (figure 8) is a horizontal bar of targets, each
with a flat bottom face of known width, captured by every camera at several bar heights. A
capture gives, per camera, one line per height; :func:`measure_targets` finds each target's
flat face in a line (centre and width in pixels), :func:`assign_targets` says which target each
detection is (from an approximate camera whose error :func:`estimate_target_mapping` finds over
all heights at once), and :func:`measure_capture` does all of it for a whole capture. The
target centres are
the ``(x, z, u)`` points that calibrate the camera; the widths give the resolution look-up
table (:mod:`catenary_linescan.calibration`).

A plain point list (CSV ``camera,x_mm,z_mm,u_px``) is accepted instead of a capture.
"""

from __future__ import annotations

import csv
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from catenary.arrays import BoolArray, FloatArray, IntArray
from catenary.domain import CameraLines
from catenary.errors import FormatError, UserError

from .calibration import direct_linear_transform
from .camera import LineScanCamera

__all__ = [
    "CAPTURE_FORMAT",
    "CAPTURE_FORMAT_VERSION",
    "POINTS_COLUMNS",
    "CalibrationCapture",
    "CalibrationPoints",
    "TargetMapping",
    "TargetMeasurements",
    "assign_targets",
    "estimate_target_mapping",
    "measure_capture",
    "measure_targets",
    "read_capture",
    "read_points_csv",
    "write_capture",
    "write_points_csv",
]

CAPTURE_FORMAT = "catenary-calibration"
CAPTURE_FORMAT_VERSION = 1
POINTS_COLUMNS = ("camera", "x_mm", "z_mm", "u_px")

_LINE_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16))

_EDGE_HALF_WIDTH = 2
"""Samples either side of a first-difference peak used to place an edge."""

MAD_TO_SIGMA = 1.4826
"""Standard deviation of a normal distribution over its median absolute deviation."""


# -- in-memory forms ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class CalibrationCapture:
    """A calibration capture (FORMATS.md, "Calibration captures").

    Attributes
    ----------
    flat_width_mm : float
        Width of every target's flat face [mm].
    target_x_mm : ndarray, shape (T,)
        Roof-frame ``x`` of each target's centre [mm].
    heights_mm : ndarray, shape (H,)
        Roof-frame ``z`` of the flat faces at each bar height [mm].
    cameras : dict of str to CameraLines
        Per camera, ``lines`` uint8 or uint16 ``[H, W]`` and its ``bit_depth``.
    """

    flat_width_mm: float
    target_x_mm: FloatArray
    heights_mm: FloatArray
    cameras: dict[str, CameraLines]

    def __post_init__(self) -> None:
        targets = np.asarray(self.target_x_mm, dtype=np.float64)
        heights = np.asarray(self.heights_mm, dtype=np.float64)
        problem = _capture_problem(self.flat_width_mm, targets, heights, self.cameras)
        if problem:
            raise ValueError(problem)
        object.__setattr__(self, "target_x_mm", targets)
        object.__setattr__(self, "heights_mm", heights)
        object.__setattr__(self, "flat_width_mm", float(self.flat_width_mm))


def _capture_problem(
    flat_width_mm: float,
    targets: FloatArray,
    heights: FloatArray,
    cameras: Mapping[str, CameraLines],
) -> str | None:
    if not (math.isfinite(flat_width_mm) and flat_width_mm > 0.0):
        return f"attribute /flat_width_mm = {flat_width_mm} is not a positive length"
    for field, values in (("/targets/x_mm", targets), ("/heights_mm", heights)):
        if values.ndim != 1 or values.shape[0] == 0:
            return f"{field} has shape {values.shape}, expected [n] with n >= 1"
        if not np.all(np.isfinite(values)):
            return f"{field} has a non-finite value at index {int(np.argmin(np.isfinite(values)))}"
        if np.unique(values).shape[0] != values.shape[0]:
            return f"{field} has repeated values"
    if not cameras:
        return "no cameras in /cameras"
    for name, camera in cameras.items():
        lines = camera.lines
        where = f"/cameras/{name}/lines"
        if lines.dtype not in _LINE_DTYPES:
            return f"{where} has dtype {lines.dtype}, expected uint8 or uint16"
        if lines.ndim != 2 or lines.shape[0] != heights.shape[0] or lines.shape[1] < 1:
            return (
                f"{where} has shape {lines.shape}, expected [{heights.shape[0]}, W] "
                f"for {heights.shape[0]} heights"
            )
        bits = 8 * lines.dtype.itemsize
        if not (isinstance(camera.bit_depth, int | np.integer) and 1 <= camera.bit_depth <= bits):
            return f"{where} attr bit_depth = {camera.bit_depth!r}, expected an integer 1..{bits}"
        if lines.size and int(lines.max()) > 2 ** int(camera.bit_depth) - 1:
            return (
                f"{where} has value {int(lines.max())} above the {camera.bit_depth}-bit "
                f"maximum {2 ** int(camera.bit_depth) - 1}"
            )
    return None


@dataclass(frozen=True, eq=False)
class CalibrationPoints:
    """Calibration points ``(x, z, u)`` of several cameras (the CSV point list).

    Attributes
    ----------
    camera : ndarray of str, shape (n,)
        Camera of each point.
    x_mm, z_mm : ndarray, shape (n,)
        Roof-frame position [mm].
    u_px : ndarray, shape (n,)
        Observed image coordinate in that camera [px].
    """

    camera: NDArray[np.str_]
    x_mm: FloatArray
    z_mm: FloatArray
    u_px: FloatArray

    def __post_init__(self) -> None:
        camera = np.asarray(self.camera, dtype=np.str_)
        arrays = [np.asarray(v, dtype=np.float64) for v in (self.x_mm, self.z_mm, self.u_px)]
        if camera.ndim != 1 or any(a.shape != camera.shape for a in arrays):
            raise ValueError("calibration points: camera, x_mm, z_mm, u_px must be [n] each")
        object.__setattr__(self, "camera", camera)
        for field, value in zip(("x_mm", "z_mm", "u_px"), arrays, strict=True):
            object.__setattr__(self, field, value)

    @property
    def cameras(self) -> list[str]:
        """Camera names in order of first appearance."""
        names, first = np.unique(self.camera, return_index=True)
        return [str(name) for name in names[np.argsort(first)]]

    def of_camera(self, name: str) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(x_mm, z_mm, u_px)`` of one camera's points, each shape (m,)."""
        mask = self.camera == name
        return self.x_mm[mask], self.z_mm[mask], self.u_px[mask]


# -- HDF5 captures -----------------------------------------------------------------------------


def _attribute(path: Path, node: Any, where: str, name: str) -> Any:
    if name not in node.attrs:
        raise FormatError(path, f"missing attribute {where}{name}")
    return node.attrs[name]


def _as_text(value: Any) -> str | None:
    if isinstance(value, bytes | np.bytes_):
        try:
            return bytes(value).decode()
        except UnicodeDecodeError:
            return None
    return value if isinstance(value, str) else None


def _as_int(value: Any) -> int | None:
    if isinstance(value, bool | np.bool_):
        return None
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, np.ndarray) and value.shape in ((), (1,)) and value.dtype.kind in "iu":
        return int(value.reshape(-1)[0])
    return None


def _as_float(value: Any) -> float | None:
    if isinstance(value, bool | np.bool_):
        return None
    if isinstance(value, int | float | np.integer | np.floating):
        return float(value)
    if isinstance(value, np.ndarray) and value.shape in ((), (1,)) and value.dtype.kind in "iuf":
        return float(value.reshape(-1)[0])
    return None


def _dataset(path: Path, file: Any, name: str) -> Any:
    node = file.get(name)
    if node is None:
        raise FormatError(path, f"missing dataset /{name}")
    if not isinstance(node, h5py.Dataset):
        raise FormatError(path, f"/{name} is a group, expected a dataset")
    return node


def _real_vector(path: Path, file: Any, name: str) -> FloatArray:
    node = _dataset(path, file, name)
    if node.dtype.kind not in "iuf":
        raise FormatError(path, f"/{name} has dtype {node.dtype}, expected float64")
    if node.ndim != 1 or node.shape[0] == 0:
        raise FormatError(path, f"/{name} has shape {node.shape}, expected [n] with n >= 1")
    values = np.asarray(node[()], dtype=np.float64)
    bad = ~np.isfinite(values)
    if np.any(bad):
        index = int(np.argmax(bad))
        raise FormatError(path, f"/{name}[{index}] = {values[index]} is not finite")
    return values


def read_capture(path: str | os.PathLike[str]) -> CalibrationCapture:
    """Read and validate a calibration capture (HDF5, FORMATS.md).

    Parameters
    ----------
    path : path-like
        The ``*.h5`` file.

    Returns
    -------
    CalibrationCapture

    Raises
    ------
    catenary.errors.FormatError
        Naming the path and the field: not HDF5, wrong ``format`` or ``format_version``, a
        missing dataset or attribute, a wrong dtype or shape, a non-finite or out-of-range
        value. Unknown extra groups and attributes are ignored.
    """
    path = Path(path)
    try:
        file = h5py.File(path, "r")
    except (OSError, ValueError) as error:
        raise FormatError(path, f"cannot be opened as HDF5 ({error})") from None
    with file:
        fmt = _as_text(_attribute(path, file, "/", "format"))
        if fmt != CAPTURE_FORMAT:
            raise FormatError(
                path, f"attribute /format is {file.attrs['format']!r}, expected {CAPTURE_FORMAT!r}"
            )
        version = _as_int(_attribute(path, file, "/", "format_version"))
        if version != CAPTURE_FORMAT_VERSION:
            raise FormatError(
                path,
                f"attribute /format_version is {file.attrs['format_version']!r}, this version "
                f"of catenary reads {CAPTURE_FORMAT_VERSION}",
            )
        flat_width = _as_float(_attribute(path, file, "/", "flat_width_mm"))
        if flat_width is None or not (math.isfinite(flat_width) and flat_width > 0.0):
            raise FormatError(
                path,
                f"attribute /flat_width_mm is {file.attrs['flat_width_mm']!r}, "
                "expected a positive length in mm",
            )
        targets = _real_vector(path, file, "targets/x_mm")
        heights = _real_vector(path, file, "heights_mm")
        group = file.get("cameras")
        if not isinstance(group, h5py.Group) or len(group) == 0:
            raise FormatError(path, "missing group /cameras (one subgroup per camera)")
        cameras: dict[str, CameraLines] = {}
        for name in group:
            node = _dataset(path, file, f"cameras/{name}/lines")
            if node.dtype not in _LINE_DTYPES:
                raise FormatError(
                    path, f"/cameras/{name}/lines has dtype {node.dtype}, expected uint8 or uint16"
                )
            if node.ndim != 2 or node.shape[0] != heights.shape[0] or node.shape[1] < 1:
                raise FormatError(
                    path,
                    f"/cameras/{name}/lines has shape {node.shape}, expected "
                    f"[{heights.shape[0]}, W] for {heights.shape[0]} heights",
                )
            raw = _attribute(path, node, f"/cameras/{name}/lines attr ", "bit_depth")
            bit_depth = _as_int(raw)
            if bit_depth is None:
                raise FormatError(
                    path, f"/cameras/{name}/lines attr bit_depth is {raw!r}, expected an integer"
                )
            cameras[name] = CameraLines(lines=node[()], bit_depth=bit_depth)
        problem = _capture_problem(flat_width, targets, heights, cameras)
        if problem:
            raise FormatError(path, problem)
    return CalibrationCapture(flat_width, targets, heights, cameras)


def _replace_atomically(path: Path, write: Any, suffix: str) -> None:
    """Write to a temporary file beside ``path`` with ``write(tmp_path)``, then rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(handle)
    try:
        write(Path(temporary))
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def write_capture(path: str | os.PathLike[str], capture: CalibrationCapture) -> None:
    """Write a calibration capture (HDF5, FORMATS.md); the file appears whole or not at all.

    Parameters
    ----------
    path : path-like
        The ``*.h5`` file, replaced if it exists.
    capture : CalibrationCapture
        What to write.
    """

    def write(temporary: Path) -> None:
        with h5py.File(temporary, "w") as file:
            file.attrs["format"] = CAPTURE_FORMAT
            file.attrs["format_version"] = np.int64(CAPTURE_FORMAT_VERSION)
            file.attrs["flat_width_mm"] = np.float64(capture.flat_width_mm)
            file.create_dataset("targets/x_mm", data=capture.target_x_mm.astype(np.float64))
            file.create_dataset("heights_mm", data=capture.heights_mm.astype(np.float64))
            for name, camera in capture.cameras.items():
                dataset = file.create_dataset(f"cameras/{name}/lines", data=camera.lines)
                dataset.attrs["bit_depth"] = np.int64(camera.bit_depth)

    _replace_atomically(Path(path), write, ".h5")


# -- CSV point lists ---------------------------------------------------------------------------


def read_points_csv(path: str | os.PathLike[str]) -> CalibrationPoints:
    """Read a calibration point list: CSV with columns ``camera,x_mm,z_mm,u_px``.

    Columns may come in any order; extra columns are ignored.

    Parameters
    ----------
    path : path-like
        The CSV file.

    Returns
    -------
    CalibrationPoints

    Raises
    ------
    catenary.errors.FormatError
        Naming the path, line and column: unreadable file, a missing column, an empty camera
        name, a value that is not a finite number, or no points at all.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8") as stream:
            reader = csv.DictReader(stream)
            header = [name.strip() for name in (reader.fieldnames or [])]
            missing = [name for name in POINTS_COLUMNS if name not in header]
            if missing:
                raise FormatError(
                    path, f"missing column(s) {', '.join(missing)}; expected camera,x_mm,z_mm,u_px"
                )
            reader.fieldnames = header
            cameras: list[str] = []
            values: list[tuple[float, float, float]] = []
            for row in reader:
                line = reader.line_num
                camera = (row["camera"] or "").strip()
                if not camera:
                    raise FormatError(path, f"line {line}: empty camera name")
                numbers = []
                for column in POINTS_COLUMNS[1:]:
                    text = (row[column] or "").strip()
                    try:
                        number = float(text)
                    except ValueError:
                        number = math.nan
                    if not math.isfinite(number):
                        raise FormatError(
                            path, f"line {line}: {column} {text!r} is not a finite number"
                        )
                    numbers.append(number)
                cameras.append(camera)
                values.append((numbers[0], numbers[1], numbers[2]))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise FormatError(path, f"cannot be read as CSV ({error})") from None
    if not values:
        raise FormatError(path, "no calibration points")
    array = np.array(values, dtype=np.float64)
    return CalibrationPoints(
        np.array(cameras, dtype=np.str_), array[:, 0], array[:, 1], array[:, 2]
    )


def write_points_csv(path: str | os.PathLike[str], points: CalibrationPoints) -> None:
    """Write a calibration point list (CSV ``camera,x_mm,z_mm,u_px``), floats round-tripping.

    Parameters
    ----------
    path : path-like
        The CSV file, replaced if it exists.
    points : CalibrationPoints
        What to write.
    """

    def write(temporary: Path) -> None:
        with temporary.open("w", newline="", encoding="utf-8") as stream:
            writer = csv.writer(stream, lineterminator="\n")
            writer.writerow(POINTS_COLUMNS)
            writer.writerows(
                (str(camera), repr(float(x)), repr(float(z)), repr(float(u)))
                for camera, x, z, u in zip(
                    points.camera, points.x_mm, points.z_mm, points.u_px, strict=True
                )
            )

    _replace_atomically(Path(path), write, ".csv")


# -- measuring the targets in a line ------------------------------------------------------------


def _runs(mask: BoolArray) -> tuple[IntArray, IntArray]:
    """Starts and (exclusive) ends of the runs of True in a 1-D mask."""
    padded = np.concatenate([[False], mask, [False]])
    change = np.flatnonzero(padded[1:] != padded[:-1])
    return change[0::2].astype(np.int64), change[1::2].astype(np.int64)


def _segment_argmax(values: FloatArray, starts: IntArray, ends: IntArray) -> IntArray:
    """Index of the maximum of ``values[start:end]`` for each segment (vectorised)."""
    if starts.size == 0:
        return np.zeros(0, dtype=np.int64)
    length = int(np.max(ends - starts))
    index = starts[:, np.newaxis] + np.arange(length)[np.newaxis, :]
    inside = index < ends[:, np.newaxis]
    window = np.where(inside, values[np.clip(index, 0, values.shape[0] - 1)], -np.inf)
    return np.asarray(index[np.arange(starts.size), np.argmax(window, axis=1)], dtype=np.int64)


def _edge_positions(gradient: FloatArray, coarse: IntArray, sign: float) -> FloatArray:
    """Sub-pixel edge positions [px] at the peaks of a first-order difference.

    ``gradient[j]`` (the difference ``line[j + 1] - line[j]``, smoothed) sits at ``j + 0.5``;
    ``sign`` is +1 for rising and -1 for falling edges; ``coarse`` (k,) are indices near the
    peaks. The edge is the peak of the first difference, i.e. the zero crossing of the
    second-order difference (the inflection of the grey-level profile), located by fitting a
    Gaussian to the peak: a parabola to the logarithm of the ``2 · _EDGE_HALF_WIDTH + 1``
    samples around it, weighted by the squared samples and restricted to the peak's own lobe
    (contiguous positive samples). A blurred step's first difference is nearly Gaussian, so
    the fit is unbiased where a parabola through three samples is not.
    """
    n = gradient.shape[0]
    half = _EDGE_HALF_WIDTH
    # move each coarse index onto the local maximum of the difference
    near = np.clip(coarse[:, np.newaxis] + np.arange(-half, half + 1), 0, n - 1)
    rows = np.arange(coarse.shape[0])
    peak_index = near[rows, np.argmax(sign * gradient[near], axis=1)]
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    index = peak_index[:, np.newaxis] + np.arange(-half, half + 1)
    inside = (index >= 0) & (index < n)
    samples = np.where(inside, sign * gradient[np.clip(index, 0, n - 1)], 0.0)
    positive = samples > 0.0
    right = np.cumprod(positive[:, half:], axis=1).astype(bool)
    left = np.cumprod(positive[:, half::-1], axis=1).astype(bool)[:, ::-1]
    lobe = np.concatenate([left[:, :-1], right], axis=1)
    weight = np.where(lobe, samples * samples, 0.0)
    log_samples = np.log(np.where(lobe, samples, 1.0))
    design = np.stack([np.ones_like(offsets), offsets, offsets * offsets], axis=1)
    normal = np.einsum("ki,ij,il->kjl", weight, design, design) + 1e-12 * np.eye(3)
    rhs = np.einsum("ki,ij,ki->kj", weight, design, log_samples)
    coefficients = np.linalg.solve(normal, rhs[..., np.newaxis])[..., 0]
    centroid = (weight * offsets).sum(axis=1) / np.maximum(weight.sum(axis=1), 1e-300)
    with np.errstate(invalid="ignore", divide="ignore"):
        vertex = -coefficients[:, 1] / (2.0 * coefficients[:, 2])
    fitted = (coefficients[:, 2] < 0.0) & (np.abs(vertex) <= 1.0)
    shift = np.where(fitted, vertex, centroid)
    return np.asarray(peak_index + 0.5 + shift, dtype=np.float64)


def measure_targets(
    line: ArrayLike,
    bit_depth: int,
    expected_targets: int | None = None,
    *,
    background_window_px: int = 151,
    min_contrast: float = 0.02,
    min_width_px: float = 4.0,
    edge_window_px: int = 8,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Find the calibration targets' bright flat faces in one line (the paper, section 3.2).

    1. Grey levels are scaled to ``[0, 1]`` by the bit depth, so 8- and 16-bit data behave
       alike; the noise is estimated robustly (MAD) from the first-order difference.
    2. Background: a mean filter of ``background_window_px`` over the 3-px smoothed line,
       started from its lower envelope and recomputed with the bright pixels replaced by the
       background, so that wide bright targets do not lift it.
    3. Candidates: runs brighter than the background by more than
       ``max(8 · noise, min_contrast)``, runs closer than ``edge_window_px`` joined (a face
       and its dimmer sides are one target), at least ``min_width_px`` long; runs touching
       an end of the line (targets cut by the field of view) are dropped.
    4. Edges: the face's rising edge is the largest first-order difference between the run's
       start (less ``edge_window_px``) and its brightest pixel, the falling edge the most
       negative one after it. Each edge is placed at the zero crossing of the second-order
       difference, which is the peak of the first-order difference (the inflection of the
       grey-level profile): there a symmetric blur leaves the edge of a uniform face where it
       is, whereas the second difference's extremes move outward and inward with the blur.
       Sub-pixel: a Gaussian is fitted to the first difference's peak (a parabola to the
       logarithm of the five samples around it, weighted by their squares), which is
       unbiased for a blurred step where a three-sample parabola is not.
    5. Centre = mid of the two edges; width = their distance. Detections narrower than
       ``min_width_px``, whose two edges differ in strength by more than a factor 3 (a
       face cut by the line's end, a slope), or fainter than 30 % of the median contrast of
       the detections (smudges, reflections) are dropped; with ``expected_targets`` only
       that many, of the highest contrast, are kept.

    Measured on simulated lines (faces 9-26 px, blur sigma 0.5-1.5 px, noise 0.5 % of full
    scale, 8 to 16 bits) the centres are within 0.1 px and the widths within 0.2 px.

    Parameters
    ----------
    line : array_like, shape (W,)
        One grey-level line (uint8, uint16 or any real type).
    bit_depth : int
        Bits per pixel (1..16); the full scale is ``2**bit_depth - 1``.
    expected_targets : int or None, default None
        At most this many detections are returned (the targets on the bar).
    background_window_px : int, default 151
        Mean-filter length for the background [px]; several times a target's width.
    min_contrast : float, default 0.02
        Smallest face brightness above background, as a fraction of full scale [-].
    min_width_px : float, default 4.0
        Narrowest face accepted [px].
    edge_window_px : int, default 8
        How far outside a candidate run its edges are searched, and how close to the line's
        ends an edge may be [px]; at least the blur's extent.

    Returns
    -------
    centre_px : ndarray, shape (k,)
        Face centres [px], increasing.
    flat_width_px : ndarray, shape (k,)
        Face widths between the edges [px].
    contrast : ndarray, shape (k,)
        Face brightness above background, fraction of full scale [-].
    """
    values = np.asarray(line)
    if values.ndim != 1:
        raise ValueError(f"line has shape {values.shape}, expected (W,)")
    if not 1 <= int(bit_depth) <= 16:
        raise ValueError(f"bit_depth = {bit_depth} is not in 1..16")
    empty = np.zeros(0, dtype=np.float64)
    if values.shape[0] < 4 * edge_window_px:
        return empty, empty.copy(), empty.copy()
    full_scale = float(2 ** int(bit_depth) - 1)
    grey = values.astype(np.float64) / full_scale
    gradient = np.diff(grey)
    noise = MAD_TO_SIGMA * float(np.median(np.abs(gradient - np.median(gradient)))) / math.sqrt(2)
    noise = max(noise, 1.0 / (math.sqrt(12.0) * full_scale))

    smooth = ndimage.uniform_filter1d(grey, 3, mode="nearest")
    window = min(int(background_window_px), grey.shape[0])
    # start from the lower envelope so that wide bright targets cannot lift the background
    background = ndimage.uniform_filter1d(
        ndimage.minimum_filter1d(smooth, window, mode="nearest"), window, mode="nearest"
    )
    for _ in range(3):
        bright = smooth > background + 3.0 * noise
        background = ndimage.uniform_filter1d(
            np.where(bright, background, smooth), window, mode="nearest"
        )
    excess = smooth - background
    threshold = max(8.0 * noise, float(min_contrast))
    starts, ends = _runs(excess > threshold)
    # a target's face and its less bright sides are one candidate even if noise splits them
    joined = starts[1:] - ends[:-1] <= edge_window_px
    starts = np.concatenate([starts[:1], starts[1:][~joined]])
    ends = np.concatenate([ends[:-1][~joined], ends[-1:]])
    # a candidate touching an end of the line is a target cut by the field of view
    whole = ((ends - starts) >= min_width_px) & (starts > 0) & (ends < grey.shape[0])
    starts, ends = starts[whole], ends[whole]
    if starts.size == 0:
        return empty, empty.copy(), empty.copy()

    brightest = _segment_argmax(smooth, starts, ends)
    contrast = excess[brightest]
    smooth_gradient = np.diff(smooth)
    # rising edge: between the run's start (less a margin) and its brightest pixel
    margin = int(edge_window_px)
    lo = np.clip(starts - margin, 0, gradient.shape[0] - 1)
    rising = _segment_argmax(smooth_gradient, lo, np.maximum(brightest, lo + 1))
    hi = np.clip(ends + margin, 1, gradient.shape[0])
    falling = _segment_argmax(-smooth_gradient, np.minimum(brightest, hi - 1), hi)
    rise, fall = smooth_gradient[rising], -smooth_gradient[falling]
    left = _edge_positions(smooth_gradient, rising, 1.0)
    right = _edge_positions(smooth_gradient, falling, -1.0)

    centre = 0.5 * (left + right)
    width = right - left
    with np.errstate(invalid="ignore"):
        keep = (
            np.isfinite(centre)
            & (width >= min_width_px)
            & (rising >= margin)
            & (falling < gradient.shape[0] - margin)
            # a face has two edges of similar strength; noise at a cut face does not
            & (np.minimum(rise, fall) >= 0.3 * np.maximum(rise, fall))
        )
    centre, width, contrast = centre[keep], width[keep], contrast[keep]
    if contrast.size:
        strong = contrast >= 0.3 * np.median(contrast)
        centre, width, contrast = centre[strong], width[strong], contrast[strong]
    if expected_targets is not None and centre.shape[0] > expected_targets:
        best = np.sort(np.argsort(-contrast, kind="stable")[: max(int(expected_targets), 0)])
        centre, width, contrast = centre[best], width[best], contrast[best]
    order = np.argsort(centre)
    return (
        np.asarray(centre[order], dtype=np.float64),
        np.asarray(width[order], dtype=np.float64),
        np.asarray(contrast[order], dtype=np.float64),
    )


def _nearest_difference(values: FloatArray, ordered: FloatArray) -> FloatArray:
    """``values`` minus the nearest element of the sorted non-empty 1-D ``ordered``."""
    above = np.searchsorted(ordered, values)
    below_gap = values - ordered[np.maximum(above - 1, 0)]
    above_gap = values - ordered[np.minimum(above, ordered.shape[0] - 1)]
    return np.asarray(
        np.where(np.abs(below_gap) <= np.abs(above_gap), below_gap, above_gap), dtype=np.float64
    )


def _predicted_targets(
    camera: LineScanCamera, target_x_mm: FloatArray, height_mm: float
) -> FloatArray:
    """Predicted image coordinates [px] of the targets, NaN behind the camera, shape (T,)."""
    predicted = camera.project(target_x_mm, height_mm)
    in_front = np.isfinite(predicted) & (camera.depth_mm(target_x_mm, height_mm) > 0.0)
    return np.asarray(np.where(in_front, predicted, np.nan), dtype=np.float64)


def _default_tolerance_px(predicted: FloatArray, pixels: int) -> float:
    spacing = np.diff(np.sort(predicted[np.isfinite(predicted)]))
    return float(np.min(spacing)) / 3.0 if spacing.size else float(pixels)


_SCALES = np.linspace(0.94, 1.06, 13)
"""Scales tried between an approximate camera's target spacing and the detected one."""


@dataclass(frozen=True)
class TargetMapping:
    """How an approximate camera's predicted targets map onto the detections [px].

    ``u_detected ≈ centre_px + offset_px + scale · (u_predicted - centre_px)`` with
    ``centre_px`` the middle of the line, so that offset and scale are independent.
    """

    offset_px: float
    scale: float
    centre_px: float

    def apply(self, predicted_px: FloatArray) -> FloatArray:
        """The mapped predictions [px], same shape."""
        return np.asarray(
            self.centre_px + self.offset_px + self.scale * (predicted_px - self.centre_px),
            dtype=np.float64,
        )


def _mapping_scores(
    line: FloatArray,
    predicted: FloatArray,
    offsets: FloatArray,
    scales: FloatArray,
    centre_px: float,
    tolerance_px: float,
    pixels: int,
) -> IntArray:
    """Score of each candidate mapping ``(offsets[i], scales[i])`` for one line.

    A target whose mapped prediction has a detection within the tolerance earns 1; a target
    mapped well inside the line (more than the tolerance from its ends) that no detection
    explains costs 1.
    """
    finite = predicted[np.isfinite(predicted)]
    if line.size == 0 or finite.size == 0:
        return np.zeros(offsets.shape, dtype=np.int64)
    moved = centre_px + offsets[:, np.newaxis] + scales[:, np.newaxis] * (finite - centre_px)
    explained = np.abs(_nearest_difference(moved, line)) <= tolerance_px
    inside = (moved >= tolerance_px) & (moved <= pixels - 1 - tolerance_px)
    return np.asarray(
        np.count_nonzero(explained, axis=1) - np.count_nonzero(inside & ~explained, axis=1),
        dtype=np.int64,
    )


def estimate_target_mapping(
    centres_px: Sequence[ArrayLike],
    target_x_mm: ArrayLike,
    heights_mm: ArrayLike,
    camera: LineScanCamera,
    *,
    tolerance_px: float | None = None,
    scales: ArrayLike | None = None,
) -> TargetMapping:
    """Offset and scale between an approximate camera's predicted targets and the detections.

    Candidates: every scale in ``scales`` with every offset that puts some detection exactly
    on some target's scaled prediction, at any bar height. Each candidate is
    scored, summed over the heights: a target earns 1 when a detection lies within the
    tolerance of its mapped prediction, and a target mapped well inside the line that no
    detection explains costs 1. The best candidate wins, ties going to the smallest offset,
    then the scale nearest 1. Shifting by a whole target spacing explains nearly as many
    detections in one line, but the spacing in pixels changes with the height, so only the
    true mapping fits every height: several heights make the choice safe for errors of more
    than a spacing (tested: tilt errors of 3°, focal errors of 2.5 %, centre errors of 10 mm
    on the demo rig).

    Parameters
    ----------
    centres_px : sequence of array_like, each shape (k_h,)
        Detected face centres at each bar height [px].
    target_x_mm : array_like, shape (T,)
        Targets' roof-frame ``x`` [mm].
    heights_mm : array_like, shape (H,)
        Bar heights [mm], one per entry of ``centres_px``.
    camera : LineScanCamera
        Approximate camera.
    tolerance_px : float or None
        Match tolerance [px]; default per height, a third of the smallest predicted spacing.
    scales : array_like or None
        Scales tried [-]; default 0.94 to 1.06 in 1 % steps for several lines, and 1 alone
        for a single line (which cannot tell a scale from a shift by a target).

    Returns
    -------
    TargetMapping
        The identity mapping when nothing was detected.
    """
    targets = np.asarray(target_x_mm, dtype=np.float64)
    heights = np.asarray(heights_mm, dtype=np.float64).reshape(-1)
    lines = [np.sort(np.asarray(c, dtype=np.float64).reshape(-1)) for c in centres_px]
    if len(lines) != heights.shape[0]:
        raise ValueError(f"{len(lines)} lines of detections for {heights.shape[0]} heights")
    middle = (camera.pixels - 1) / 2.0
    predictions = [_predicted_targets(camera, targets, float(z)) for z in heights]
    if scales is None:
        scales = _SCALES if len(lines) > 1 else np.ones(1)
    offsets, scale_of = [np.zeros(0)], [np.zeros(0)]
    for line, predicted in zip(lines, predictions, strict=True):
        finite = predicted[np.isfinite(predicted)]
        pairs = line[:, np.newaxis] - middle  # (k, 1) against (1, T) for each scale
        for scale in np.asarray(scales, dtype=np.float64):  # a handful of scales
            offsets.append((pairs - scale * (finite[np.newaxis, :] - middle)).reshape(-1))
            scale_of.append(np.full(line.shape[0] * finite.shape[0], scale))
    offset, scale = np.concatenate(offsets), np.concatenate(scale_of)
    if offset.size == 0:
        return TargetMapping(0.0, 1.0, middle)
    tolerances = [
        tolerance_px if tolerance_px is not None else _default_tolerance_px(p, camera.pixels)
        for p in predictions
    ]
    # candidates closer than an eighth of the tolerance score alike: keep one of each
    step = max(min(tolerances) / 8.0, 1e-9)
    _, unique = np.unique(np.stack([np.round(offset / step), scale]), axis=1, return_index=True)
    offset, scale = offset[unique], scale[unique]
    score = np.zeros(offset.shape, dtype=np.int64)
    for line, predicted, tolerance in zip(lines, predictions, tolerances, strict=True):
        score += _mapping_scores(line, predicted, offset, scale, middle, tolerance, camera.pixels)
    best = np.flatnonzero(score == score.max())
    choice = best[np.lexsort((np.abs(scale[best] - 1.0), np.abs(offset[best])))[0]]
    return TargetMapping(float(offset[choice]), float(scale[choice]), middle)


def assign_targets(
    centre_px: ArrayLike,
    target_x_mm: ArrayLike,
    height_mm: float,
    camera: LineScanCamera | None = None,
    *,
    tolerance_px: float | None = None,
    mapping: TargetMapping | None = None,
    ascending: bool = True,
) -> IntArray:
    """Which target each detection in one line is.

    With an approximate ``camera`` (nominal mounting, or a previous calibration): the targets
    are projected at the bar height and mapped by ``mapping`` (the approximate camera's
    error as an offset and scale; by default estimated from this line alone with
    :func:`estimate_target_mapping`, which :func:`measure_capture` does over all heights at
    once). The offset is then re-searched for this line within ``tolerance_px`` of the
    mapping's (centre and distance errors shift lines at different heights differently).
    Each detection takes the nearest mapped prediction within ``tolerance_px``, a target
    going to the closest of several claimants; then a scale and offset fitted to the
    matched pairs replace the mapping and the match is repeated, twice. Tilt errors of a few
    degrees, focal errors of a few per cent and centre errors of centimetres are absorbed.

    Without a camera: the detections, in order along the line, are the targets in order of
    ``x`` (``ascending``: ``u`` grows with ``x``), which needs every target seen exactly once.

    Parameters
    ----------
    centre_px : array_like, shape (k,)
        Detected face centres [px].
    target_x_mm : array_like, shape (T,)
        Targets' roof-frame ``x`` [mm].
    height_mm : float
        Bar height: roof-frame ``z`` of the faces [mm].
    camera : LineScanCamera or None, default None
        Approximate camera.
    tolerance_px : float or None
        Largest distance between a detection and its mapped prediction [px]; default a
        third of the smallest predicted spacing between targets.
    mapping : TargetMapping or None
        Prior mapping of the predictions; None estimates it from this line.
    ascending : bool, default True
        Without a camera: whether ``u`` grows with ``x``.

    Returns
    -------
    ndarray of int, shape (k,)
        Index into ``target_x_mm`` of each detection; -1 for detections matching no target
        (spurious).

    Raises
    ------
    catenary.errors.UserError
        Without a camera, when the number of detections is not the number of targets.
    """
    centre = np.asarray(centre_px, dtype=np.float64)
    targets = np.asarray(target_x_mm, dtype=np.float64)
    k, n_targets = centre.shape[0], targets.shape[0]
    if camera is None:
        if k != n_targets:
            raise UserError(
                f"{k} targets detected at height {height_mm:g} mm, {n_targets} on the bar; "
                "an approximate camera is needed to tell which were seen"
            )
        by_x = np.argsort(targets if ascending else -targets, kind="stable")
        result = np.empty(k, dtype=np.int64)
        result[np.argsort(centre, kind="stable")] = by_x
        return result
    unassigned = np.full(k, -1, dtype=np.int64)
    predicted = _predicted_targets(camera, targets, height_mm)
    if k == 0 or not np.any(np.isfinite(predicted)):
        return unassigned
    if tolerance_px is None:
        tolerance_px = _default_tolerance_px(predicted, camera.pixels)
    if mapping is None:
        mapping = estimate_target_mapping(
            [centre], targets, [height_mm], camera, tolerance_px=tolerance_px
        )
    else:  # re-search the offset near the prior for this line
        finite = predicted[np.isfinite(predicted)]
        scaled = mapping.apply(finite) - mapping.offset_px
        offsets = (centre[:, np.newaxis] - scaled[np.newaxis, :]).reshape(-1)
        offsets = offsets[np.abs(offsets - mapping.offset_px) <= tolerance_px]
        if offsets.size:
            score = _mapping_scores(
                np.sort(centre),
                predicted,
                offsets,
                np.full(offsets.shape, mapping.scale),
                mapping.centre_px,
                tolerance_px,
                camera.pixels,
            )
            best = np.flatnonzero(score == score.max())
            offset = offsets[best[np.argmin(np.abs(offsets[best] - mapping.offset_px))]]
            mapping = TargetMapping(float(offset), mapping.scale, mapping.centre_px)
    predicted = np.where(np.isfinite(predicted), predicted, np.inf)
    mapped = mapping.apply(predicted)
    result = unassigned
    for _ in range(3):  # match, then refit scale and offset to the matches, twice
        distance = np.abs(centre[:, np.newaxis] - mapped[np.newaxis, :])
        nearest = np.argmin(distance, axis=1)
        closest = distance[np.arange(k), nearest]
        result = np.where(closest <= tolerance_px, nearest, -1).astype(np.int64)
        # a target claimed twice keeps the closer detection
        order = np.argsort(closest, kind="stable")
        claimed = result[order]
        _, first = np.unique(claimed, return_index=True)
        duplicate = np.ones(k, dtype=bool)
        duplicate[first] = False
        result[order[duplicate & (claimed >= 0)]] = -1
        used = result >= 0
        if np.count_nonzero(used) < 3:
            break
        slope, intercept = np.polyfit(predicted[result[used]], centre[used], 1)
        mapped = intercept + slope * predicted
    return result


def bootstrap_camera(
    centres_px: Sequence[ArrayLike],
    target_x_mm: ArrayLike,
    heights_mm: ArrayLike,
    pixels: int,
    *,
    name: str = "",
) -> LineScanCamera | None:
    """An approximate camera from the detections alone, when no nominal camera is known.

    At the two bar heights with the most detections, the detections (in order along the line)
    are taken to be a contiguous run of the targets (in order of ``x``, either direction):
    the field of view cuts the bar at its ends. Every such pair of runs gives a DLT camera;
    each is scored by how many detections at *all* heights lie within a third of a target
    spacing of its predicted targets (then by their RMS distance). A shift by one target fits
    two heights nearly as well as the truth, but predicts the other heights wrongly, so the
    best-scoring camera is the true one up to the DLT's error. Returns None when fewer than
    two heights have three or more detections.

    Parameters
    ----------
    centres_px : sequence of array_like, each shape (k_h,)
        Detected face centres at each bar height [px].
    target_x_mm : array_like, shape (T,)
        Targets' roof-frame ``x`` [mm].
    heights_mm : array_like, shape (H,)
        Bar heights [mm], one per entry of ``centres_px``.
    pixels : int
        Pixels on the line.
    name : str
        Camera name of the result.
    """
    targets = np.sort(np.asarray(target_x_mm, dtype=np.float64))
    heights = np.asarray(heights_mm, dtype=np.float64)
    lines = [np.sort(np.asarray(c, dtype=np.float64)) for c in centres_px]
    counts = np.array([line.shape[0] for line in lines])
    seeds = np.argsort(-counts, kind="stable")[:2]
    if seeds.shape[0] < 2 or counts[seeds].min() < 3:
        return None
    best: tuple[int, float] | None = None
    chosen: LineScanCamera | None = None
    for order in (targets, targets[::-1]):
        runs = [
            [order[s : s + counts[h]] for s in range(targets.shape[0] - counts[h] + 1)]
            for h in seeds
        ]
        for first in runs[0]:
            for second in runs[1]:
                x = np.concatenate([first, second])
                z = np.repeat(heights[seeds], counts[seeds])
                u = np.concatenate([lines[seeds[0]], lines[seeds[1]]])
                matrix, conditioning = direct_linear_transform(x, z, u)
                if conditioning < 1e-12:
                    continue
                with np.errstate(divide="ignore", invalid="ignore"):
                    camera = LineScanCamera(name, pixels, matrix)
                    predicted = camera.project(targets[np.newaxis, :], heights[:, np.newaxis])
                matched, squares = 0, 0.0
                for line, row in zip(lines, predicted, strict=True):
                    if line.shape[0] == 0 or not np.all(np.isfinite(row)):
                        continue
                    tolerance = np.min(np.abs(np.diff(np.sort(row)))) / 3.0
                    distance = np.min(np.abs(line[:, np.newaxis] - row[np.newaxis, :]), axis=1)
                    close = distance < tolerance
                    matched += int(np.count_nonzero(close))
                    squares += float(np.sum(distance[close] ** 2))
                score = (matched, -squares / max(matched, 1))
                if best is None or score > best:
                    best, chosen = score, camera
    return chosen


@dataclass(frozen=True, eq=False)
class TargetMeasurements:
    """One camera's measured targets over a capture; NaN where a target was not seen.

    Attributes
    ----------
    camera : str
        Camera name.
    centre_px : ndarray, shape (H, T)
        Face centre of each target at each bar height [px].
    width_px : ndarray, shape (H, T)
        Face width [px].
    contrast : ndarray, shape (H, T)
        Face brightness above background, fraction of full scale [-].
    spurious : int
        Detections that matched no target (dropped).
    """

    camera: str
    centre_px: FloatArray
    width_px: FloatArray
    contrast: FloatArray
    spurious: int

    def points(self, capture: CalibrationCapture) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(x_mm, z_mm, u_px)`` of the targets seen, each shape (m,), for calibration."""
        seen = np.isfinite(self.centre_px)
        x = np.broadcast_to(capture.target_x_mm[np.newaxis, :], seen.shape)[seen]
        z = np.broadcast_to(capture.heights_mm[:, np.newaxis], seen.shape)[seen]
        return x.copy(), z.copy(), self.centre_px[seen]


def measure_capture(
    capture: CalibrationCapture,
    cameras: Mapping[str, LineScanCamera] | None = None,
    **measure_options: Any,
) -> dict[str, TargetMeasurements]:
    """Measure and assign the targets in every line of a capture.

    Per camera: :func:`measure_targets` on each line; with an approximate camera,
    :func:`estimate_target_mapping` over all the heights, then :func:`assign_targets` on each
    line with that mapping; without one, every target must be seen at every height.

    Parameters
    ----------
    capture : CalibrationCapture
        The capture.
    cameras : mapping of str to LineScanCamera, optional
        Approximate cameras by name (:func:`assign_targets`); a camera missing from it must see
        every target at every height.
    **measure_options
        Passed to :func:`measure_targets`.

    Returns
    -------
    dict of str to TargetMeasurements
        One per camera of the capture, in its order.
    """
    n_heights, n_targets = capture.heights_mm.shape[0], capture.target_x_mm.shape[0]
    result: dict[str, TargetMeasurements] = {}
    for name, lines in capture.cameras.items():
        approximate = None if cameras is None else cameras.get(name)
        found = [  # one line per bar height
            measure_targets(
                lines.lines[row],
                lines.bit_depth,
                n_targets if approximate is None else None,
                **measure_options,
            )
            for row in range(n_heights)
        ]
        if approximate is None and any(f[0].shape[0] != n_targets for f in found):
            approximate = bootstrap_camera(
                [f[0] for f in found],
                capture.target_x_mm,
                capture.heights_mm,
                lines.lines.shape[1],
                name=name,
            )
        mapping = None
        if approximate is not None:
            mapping = estimate_target_mapping(
                [f[0] for f in found], capture.target_x_mm, capture.heights_mm, approximate
            )
        centre = np.full((n_heights, n_targets), np.nan)
        width = centre.copy()
        contrast = centre.copy()
        spurious = 0
        for row, (centres, widths, contrasts) in enumerate(found):
            try:
                which = assign_targets(
                    centres,
                    capture.target_x_mm,
                    float(capture.heights_mm[row]),
                    approximate,
                    mapping=mapping,
                )
            except UserError as error:
                raise UserError(f"camera {name!r}: {error}") from None
            used = which >= 0
            spurious += int(np.count_nonzero(~used))
            centre[row, which[used]] = centres[used]
            width[row, which[used]] = widths[used]
            contrast[row, which[used]] = contrasts[used]
        result[name] = TargetMeasurements(name, centre, width, contrast, spurious)
    return result
