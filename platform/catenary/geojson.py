"""GeoJSON (RFC 7946) of stretches of track, placed by the WGS 84 positions of the mast
register (its optional ``latitude``, ``longitude`` columns, FORMATS.md "Mast register").

A stretch is a LineString through the positions at its ends and at every positioned mast
between them, a position between two positioned masts interpolated linearly by chainage
(spans are tens of metres: the straight line between masts is well within a map's
resolution); a stretch of no length is a Point. A stretch beyond the first or last positioned
mast has no geometry, and its feature is left out.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from catenary.arrays import FloatArray
from catenary.errors import UserError

__all__ = ["MastPositions", "feature", "feature_collection", "geojson_text", "write_geojson"]


@dataclass(frozen=True)
class MastPositions:
    """The positioned masts of one track, by chainage."""

    chainage_m: FloatArray  # (k,) ascending [m]
    longitude: FloatArray  # (k,) [degrees east, WGS 84]
    latitude: FloatArray  # (k,) [degrees north, WGS 84]

    @classmethod
    def of(cls, masts: Iterable[tuple[float, float | None, float | None]]) -> MastPositions:
        """From ``(chainage_m, latitude, longitude)`` of a track's masts; those without a
        position are skipped."""
        placed = sorted(
            (c, lon, lat) for c, lat, lon in masts if lat is not None and lon is not None
        )
        columns = np.array(placed, dtype=np.float64).reshape(-1, 3)
        return cls(columns[:, 0], columns[:, 1], columns[:, 2])

    @property
    def empty(self) -> bool:
        return bool(self.chainage_m.shape[0] == 0)

    def stretch(self, start_m: float, end_m: float) -> dict[str, Any] | None:
        """The geometry of chainage ``start_m`` to ``end_m`` (either order), or None when it
        reaches beyond the positioned masts."""
        low, high = min(start_m, end_m), max(start_m, end_m)
        if self.empty or low < self.chainage_m[0] or high > self.chainage_m[-1]:
            return None
        inside = self.chainage_m[(self.chainage_m > low) & (self.chainage_m < high)]
        chainage = np.concatenate([[low], inside, [high]] if high > low else [[low]])
        if start_m > end_m:
            chainage = chainage[::-1]
        lon = np.interp(chainage, self.chainage_m, self.longitude)
        lat = np.interp(chainage, self.chainage_m, self.latitude)
        points = [[float(x), float(y)] for x, y in zip(lon, lat, strict=True)]
        if len(points) == 1:
            return {"type": "Point", "coordinates": points[0]}
        return {"type": "LineString", "coordinates": points}


def _plain(value: Any) -> Any:
    """A property value as JSON holds it: NaN and infinities as null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def feature(geometry: dict[str, Any], properties: Mapping[str, Any]) -> dict[str, Any]:
    """A Feature of ``geometry`` with ``properties`` (NaN as null)."""
    return {
        "type": "Feature",
        "geometry": geometry,
        "properties": {key: _plain(value) for key, value in properties.items()},
    }


def feature_collection(features: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """A FeatureCollection of ``features``."""
    return {"type": "FeatureCollection", "features": list(features)}


def geojson_text(collection: dict[str, Any]) -> str:
    """``collection`` as GeoJSON text (UTF-8, numbers unrounded)."""
    return json.dumps(collection, ensure_ascii=False, allow_nan=False, indent=1) + "\n"


def write_geojson(output: Path, collection: dict[str, Any]) -> None:
    """Write ``collection`` to ``output`` through a temporary file renamed at the end (an
    interrupted write leaves no partial file); a failed write is a ``UserError`` naming
    ``output``."""
    partial = output.with_name(f".{output.name}.partial")
    try:
        partial.write_text(geojson_text(collection), encoding="utf-8")
        partial.replace(output)
    except BaseException as exc:
        partial.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise UserError(f"{output}: cannot write ({exc.strerror or exc})") from None
        raise
