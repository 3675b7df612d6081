"""Stereo matching of wire candidates across N line-scan cameras (the paper's section 3.1)."""

from .hypotheses import (
    Candidates,
    FaceWidths,
    FeatureTable,
    FloatArray,
    MatchConfig,
    Matches,
    camera_sigmas_px,
    covering_pairs,
    face_widths_mm,
    lit_chord_mm,
    match,
    pad_candidates,
)

__all__ = [
    "Candidates",
    "FaceWidths",
    "FeatureTable",
    "FloatArray",
    "MatchConfig",
    "Matches",
    "camera_sigmas_px",
    "covering_pairs",
    "face_widths_mm",
    "lit_chord_mm",
    "match",
    "pad_candidates",
]
