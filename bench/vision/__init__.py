"""The in-situ vision pipeline (thesis chapter 3): features, triangulation, absolute orientation, RANSAC.

Pipeline side: numpy / scipy / OpenCV only; never imports the simulator, the scenario runner or a dataset's truth.

The public API (``docs/vision.md``):

* :func:`match_images` / :func:`match_features` - match two images or two keypoint sets: SIFT with the thesis's
  thresholds (section 3.4.2-3.4.3), Lowe's ratio test 0.8 and the orientation filter +-20 deg (section 3.4.7,
  Eq. 106), returning a :class:`MatchResult`. :func:`detect_sift` takes grey arrays, colour arrays with an explicit
  ``channel_order`` (``"rgb"`` / ``"bgr"``), or image files.
* :func:`triangulate_midpoint` (Eq. 107-117), :func:`triangulate_linear`, :func:`triangulate_optimal` and
  :func:`triangulate` (by name) - one family: ``(T_ref_cams (V, 4, 4), x_n (V, N, 2))`` -> :class:`Triangulation`
  with a ``valid`` mask and NaN wherever invalid; :func:`triangulate_pixels` takes pixels and camera models instead.
"""

from bench.vision.features import (
    CHANNEL_ORDERS,
    Features,
    Matches,
    MatchResult,
    detect_sift,
    match_features,
    match_images,
)
from bench.vision.triangulation import (
    METHODS,
    Triangulation,
    triangulate,
    triangulate_linear,
    triangulate_midpoint,
    triangulate_optimal,
    triangulate_pixels,
)

__all__ = [
    "CHANNEL_ORDERS",
    "METHODS",
    "Features",
    "MatchResult",
    "Matches",
    "Triangulation",
    "detect_sift",
    "match_features",
    "match_images",
    "triangulate",
    "triangulate_linear",
    "triangulate_midpoint",
    "triangulate_optimal",
    "triangulate_pixels",
]
