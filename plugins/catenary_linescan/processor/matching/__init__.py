"""Stereo matching of wire candidates across N line-scan cameras (the paper's section 3.1).

The paper's trinocular check (figure 4), generalised to any number of cameras and vectorised
over the scans of a block:

1. **Pad** each camera's candidates (profile features) to ``(n, C, K)`` arrays: ``n`` scans,
   ``C`` cameras, ``K`` candidates at most per scan and camera (:func:`pad_candidates`).
2. **Enumerate** (step 1 of the paper): for camera pairs ``(a, b)`` triangulate all ``K x K``
   combinations of their candidates with the closed form (eq. 9-10), keeping points in front
   of both cameras and inside the plausible volume above the roof. Not every pair is needed:
   only pairs meeting every set of ``min_cameras`` cameras (:func:`covering_pairs`: two of
   the six for four cameras and three needed). A candidate's centre is its face's where it
   has one (the contact point), else its silhouette's middle: in scans where some cameras
   saw a face and others none, the pairs are also taken from the dark silhouettes' middles
   (the axis: a face's centre and a middle, a radius apart, never confirm each other).
3. **Verify** (steps 2-3): re-project each point into every other camera ``c`` and look up the
   nearest candidate there (one ``searchsorted`` over the block). It confirms the point when
   it lies within ``max(k · σ, floor_px)`` of the re-projection, where ``σ`` combines camera
   ``c``'s own uncertainty with those of ``a`` and ``b`` carried through the triangulation::

       σ² = σ_c² + (∂u_c/∂u_a)² σ_a² + (∂u_c/∂u_b)² σ_b²,   σ_i² = rms_i² + σ_feature²

   ``rms_i`` is camera ``i``'s calibration reprojection RMS (the paper's "average deviation
   distance of re-projection") and ``σ_feature`` the features' centre uncertainty. The
   derivatives grow when the rays of ``a`` and ``b`` meet at a shallow angle, so a point from
   two close cameras gets the wider window it needs and one from a wide baseline a narrow one.
   Candidates of opposite polarity (bright on dark against dark on bright) never match.
   A wire whose outline shows on one side only (``Candidates.outline_side``: an unworn
   wire by day behind the filter, lit from one side) is imaged at its axis a radius inward
   of that edge, at the resolution where the rays meet, not at its silhouette's middle.
4. **Resolve** conflicts so that each detection is used once (:func:`.resolve._resolve`): greedy by
   score (cameras confirming first, then the normalised residual), vectorised across the
   scans of the block in rounds; then a point that shared a detection keeps the others when
   they are enough, or a detection may be lent by a point with a camera to spare to one that
   needs it (two objects in line in one camera), and a merged silhouette
   (several objects in line, its centre and face belonging to none) supports the points whose
   images it holds. A point needs ``min_cameras`` cameras: 3 by default with three or more
   cameras (two views always intersect, so only a third verifies), which keeps a 4-camera rig
   working with one camera blinded by the sun or missing a wire. Where two cameras are
   needed (a rig of two), nothing verifies a point: the pairings of a scan's detections are
   ranked by how well their two images agree (the silhouettes' widths across the rays at
   the point, a worn face in both or in neither).
5. **Triangulate** each accepted point from all the cameras that confirmed it (least squares
   on the rays, then Gauss-Newton on the reprojection error:
   :func:`catenary_linescan.triangulation.triangulate`), from the worn face's midpoints where
   two cameras at least saw the face (the contact point), else from the middles of the
   wire's silhouettes (its axis; a radius inward of the one edge of its outline where only
   one shows, the radius measured in the block where the outline's edges bound the wire
   from both sides, and steps 2-5 done again with it), with a leave-one-out check that
   drops a camera whose image the others do not predict. A camera whose candidate is wider
   than the widest wire (``max_wire_width_mm``), whatever its polarity, or whose dark
   silhouette is wider than the point's other silhouettes sees a clamp on the wire or
   objects in line: it gives no axis, a dark one only a worn face clear inside it (a lit
   part's face is its own), and a point without two cameras left has no position (a new
   wire at a dropper clamp).
6. **Two views**: points of two cameras made of the detections left unused, where both saw a
   face, are returned unverified (``Matches.verified``): tracking takes them only where they
   continue a wire it follows (a blind camera and a missed detection at once).
7. **Separate**: of two points of a scan closer than two wires can be apart (30 mm), the
   weaker is one wire seen twice and goes.

:func:`face_widths_mm` then measures the worn face of each point in every confirming camera:
the rays through the face's two edges are cut with the face's plane through the contact point
(horizontal in the track frame, so tilted by the body's roll in the roof frame), which is the
camera model's exact resolution there; the rig's resolution look-up table times the width in
pixels is the cross-check. The cameras' widths are combined robustly (median, then the
precision-weighted mean of the cameras that agree with it).

Modules, in the order of the steps: :mod:`.candidates` (1), :mod:`.hypotheses` (2-3),
:mod:`.resolve` (4), :mod:`.triangulate` (5), :mod:`.pipeline` (:func:`match`: the steps in
order, 6 and 7), :mod:`.face_widths`; :mod:`.config` holds the settings and :mod:`.geometry`
the cameras' models in arrays that the steps share. :mod:`.evidence` reads the lines' pixels
where a point would be in the cameras that did not confirm it (the processor leaves a point
that one of them shows only sky for unverified: a ghost).
"""

from .candidates import Candidates, FeatureTable, camera_sigmas_px, pad_candidates
from .config import CONTACT_WIRE_WIDTH_MM, MatchConfig
from .face_widths import FaceWidths, face_widths_mm, lit_chord_mm
from .hypotheses import covering_pairs
from .pipeline import match
from .triangulate import Matches

__all__ = [
    "CONTACT_WIRE_WIDTH_MM",
    "Candidates",
    "FaceWidths",
    "FeatureTable",
    "MatchConfig",
    "Matches",
    "camera_sigmas_px",
    "covering_pairs",
    "face_widths_mm",
    "lit_chord_mm",
    "match",
    "pad_candidates",
]
