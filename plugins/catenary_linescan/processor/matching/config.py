"""Settings of the matching."""

from __future__ import annotations

from dataclasses import dataclass

CONTACT_WIRE_WIDTH_MM = (10.6, 14.8)
"""Narrowest and widest contact wire the features look for: EN 50149 AC-80 to AC-150 and
TB/T 2809 85 to 150 (``reference/wire-profiles.md``)."""


@dataclass(frozen=True)
class MatchConfig:
    """Settings of the matching (lengths in mm, image coordinates in px).

    Attributes
    ----------
    max_candidates : int
        Most candidates kept per scan and camera (the strongest by contrast): ``K``'s cap.
        The field's systems follow 10-12 wires; with messengers and fittings 24 leaves room.
    feature_sigma_px : float
        Standard deviation of a candidate's centre from the features [px].
    confirm_sigmas : float
        Confirmation window in standard deviations of the predicted residual (``k``).
    floor_px : float
        Narrowest confirmation window [px]: a floor under ``k · σ`` for what the noise model
        does not hold (blur, a wire's outline seen from different sides).
    min_cameras : int or None
        Cameras a point needs; None: 3 with three cameras or more, else 2.
    x_range_mm, z_range_mm : tuple of float
        Roof-frame volume in which points are plausible (messengers included).
    match_polarity : bool
        Candidates of opposite (non-zero) polarity never match.
    contact_from_faces : bool
        Triangulate the contact point from the face's midpoints where two cameras at least
        saw the face (else the wire's axis from the middles of its silhouettes).
    support_merged : bool
        Let merged silhouettes support points (step 4 of the module docstring).
    covering_pairs : bool
        Enumerate only the camera pairs that meet every set of ``min_cameras`` cameras
        (:func:`covering_pairs`), else every pair.
    two_view : bool
        Also return the points of two cameras made of detections left unused (unverified,
        ``Matches.verified`` false) where both saw a worn face, for tracking to take where
        they continue a wire.
    max_wire_width_mm : float
        The widest wire [mm]: a silhouette wider than that (a clamp on the wire, objects in
        line) gives no axis (step 5). The processor sets it from its ``wire_width_mm``.
    min_wire_width_mm : float
        The narrowest wire [mm]: with ``max_wire_width_mm`` the range of the radius measured
        from outlines (step 5). The processor sets it from its ``wire_width_mm``.
    wire_radius_mm : float
        Radius of the wire [mm] assumed where a candidate's outline shows on one side only
        (``outline_side``: :func:`.geometry._outline_axis`) until step 5 measures it (then
        the matching is done again with the radius measured). The processor sets it from its
        ``wire_width_mm``.
    min_separation_mm : float
        Two points of one scan closer than this are one wire seen twice, or a wire and what
        rests on it; the weaker goes (:func:`.pipeline._separate`). Wires are 11-15 mm
        thick: two closer than this touch.
    level_separation_mm : float
        Two verified points side by side (a height apart under half their distance across)
        at least this far apart across are two wires, even closer than ``min_separation_mm``
        (a turnout's, which meet at one height): the widest wire (15 mm) and the blur, within
        which they make one image (the tracker's ``CROSSING_MM``). ``min_separation_mm``
        alone lost one of a turnout's wires for a metre on each side of their crossing. Two
        points located by their worn faces are two wires from ``min_wire_width_mm`` apart:
        the cameras saw two faces.
    """

    max_candidates: int = 24
    feature_sigma_px: float = 0.15
    confirm_sigmas: float = 4.0
    floor_px: float = 0.6
    min_cameras: int | None = None
    x_range_mm: tuple[float, float] = (-3000.0, 3000.0)
    z_range_mm: tuple[float, float] = (300.0, 6000.0)
    match_polarity: bool = True
    contact_from_faces: bool = True
    support_merged: bool = True
    covering_pairs: bool = True
    two_view: bool = True
    max_wire_width_mm: float = CONTACT_WIRE_WIDTH_MM[1]
    min_wire_width_mm: float = CONTACT_WIRE_WIDTH_MM[0]
    wire_radius_mm: float = 0.25 * (CONTACT_WIRE_WIDTH_MM[0] + CONTACT_WIRE_WIDTH_MM[1])
    min_separation_mm: float = 30.0
    level_separation_mm: float = 20.0

    def cameras_needed(self, cameras: int) -> int:
        if self.min_cameras is not None:
            return max(2, min(self.min_cameras, cameras))
        return 3 if cameras >= 3 else 2
