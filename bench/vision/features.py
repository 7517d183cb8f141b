"""SIFT keypoints, Lowe's ratio test and the orientation-consistency filter (thesis section 3.4).

* :func:`detect_sift` - OpenCV SIFT with the thesis's thresholds (section 3.4.2-3.4.3: contrast 0.03 on the DoG value
  of an image scaled to [0, 1], edge ratio r = 10). OpenCV divides its ``contrastThreshold`` by the number of layers
  per octave before applying it, so Lowe's 0.03 is ``contrastThreshold = 0.03 * nOctaveLayers`` (0.09 with the
  default 3 layers; OpenCV's documentation says the same); the mapping is done here, once.
* :func:`match_descriptors` - nearest neighbour in descriptor space, rejected if the nearest is farther than
  ``ratio`` (0.8) times the second nearest (section 3.4.7); optionally mutual (cross-checked).
* :func:`orientation_difference` - Eq. 106: the keypoint-orientation change wrapped to (-180, 180] deg. As printed,
  Eq. 106 takes the ``min`` of the three candidates ``d - 360, d, d + 360``, which would always return ``d - 360``;
  the intended one is the candidate of smallest magnitude, which is what is computed.
* :func:`orientation_filter` - keep the matches whose orientation change lies within ``tol_deg`` (20 deg, Lowe's
  suggestion quoted in section 3.4.7) of the prevailing change (the peak of the histogram of Figure 28).

* :func:`match_features` / :func:`match_images` - the two stages together with the thesis's defaults: the public
  "match two images" call, returning a :class:`MatchResult` (pixels of both, indices, distances, counts per stage).

Coordinates are pixels in OpenCV's convention ((0, 0) is the centre of the top-left pixel). Undistortion of the
keypoint coordinates is the camera model's business (``bench.camera``); detection runs on the image as taken.

Channel order: SIFT runs on grey levels, and the grey of a colour image depends on which channel is red
(``0.299 R + 0.587 G + 0.114 B``); ``cv2.imread`` gives BGR, the bench's renderer and
:meth:`bench.dataset.View.image` give RGB. A 3- or 4-channel array is therefore refused unless the caller says which
it is (``channel_order="rgb"`` or ``"bgr"``); a grey ``(H, W)`` array needs nothing; an image file (a path) is
decoded by Pillow (:func:`bench.dataset.read_image`), which knows its own channel order.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bench.errors import ConfigError

#: Lowe's DoG contrast threshold and edge ratio as used in the thesis (section 3.4.2-3.4.3).
CONTRAST_THRESHOLD = 0.03
EDGE_THRESHOLD = 10.0
RATIO = 0.8
ORIENTATION_TOL_DEG = 20.0
#: Accepted values of ``channel_order`` for 3- or 4-channel images (a 4th channel, alpha, is ignored).
CHANNEL_ORDERS = ("rgb", "bgr")


@dataclass(frozen=True)
class Features:
    """Keypoints of one image.

    Attributes
    ----------
    uv : ndarray (N, 2)
        Pixel coordinates (OpenCV convention), as detected (distorted image).
    angle_deg : ndarray (N,)
        Keypoint orientation in (-180, 180] deg, counter-clockwise in the image as displayed (y down), i.e. the
        OpenCV angle mapped from [0, 360) and negated to be the usual mathematical sense of section 3.4.4.
    size : ndarray (N,)
        Keypoint diameter (px).
    response : ndarray (N,)
    descriptors : ndarray (N, 128) float32
    """

    uv: np.ndarray
    angle_deg: np.ndarray
    size: np.ndarray
    response: np.ndarray
    descriptors: np.ndarray

    def __len__(self) -> int:
        return len(self.uv)

    def subset(self, idx) -> Features:
        """The keypoints ``idx`` (indices or boolean mask)."""
        return Features(self.uv[idx], self.angle_deg[idx], self.size[idx], self.response[idx], self.descriptors[idx])


@dataclass(frozen=True)
class Matches:
    """Putative correspondences between two :class:`Features` sets: ``i1[k]`` in image 1 <-> ``i2[k]`` in image 2."""

    i1: np.ndarray
    i2: np.ndarray
    distance: np.ndarray
    ratio: np.ndarray  # nearest / second-nearest descriptor distance

    def __len__(self) -> int:
        return len(self.i1)

    def subset(self, keep) -> Matches:
        return Matches(self.i1[keep], self.i2[keep], self.distance[keep], self.ratio[keep])


def _read_image(path) -> np.ndarray:
    """An 8-bit image file (decoded by Pillow: :func:`bench.dataset.read_image`) as grey; one-line error naming
    the file if missing or unreadable."""
    from bench.dataset import check_image_file, read_image

    path = Path(path)
    if path.is_dir():
        raise ConfigError(path, "<file>", "a folder, not an image file")
    if not path.is_file():
        raise ConfigError(path, "<file>", "image not found")
    check_image_file(path)
    img = read_image(path)
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img


def _grey(image, channel_order=None, name="image") -> np.ndarray:
    """The grey (H, W) uint8 image SIFT runs on, from a path or an (H, W[, 1|3|4]) uint8 array (see the module notes
    on ``channel_order``)."""
    if channel_order is not None and channel_order not in CHANNEL_ORDERS:
        raise ValueError(f"channel_order: expected one of {CHANNEL_ORDERS} (or None for grey images and files), "
                         f"got {channel_order!r}")
    if isinstance(image, (str, os.PathLike)):
        if channel_order is not None:
            raise ValueError(f"channel_order: not used for an image file ({image}): OpenCV reads the file's own "
                             f"channel order; pass channel_order only with an array")
        return _read_image(image)
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.size and img.dtype != np.uint8:
        raise ValueError(f"{name}: expected uint8 pixels, got {img.dtype}")
    if img.ndim == 3 and img.shape[2] in (3, 4):
        if channel_order is None:
            raise ValueError(f"{name}: a {img.shape[2]}-channel image needs channel_order='rgb' or 'bgr' (cv2.imread "
                             f"gives 'bgr'; the renderer and bench.dataset.View.image give 'rgb'): the grey levels "
                             f"SIFT sees depend on it")
        code = cv2.COLOR_RGB2GRAY if channel_order == "rgb" else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), code)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f"{name}: expected an (H, W) grey or (H, W, 3|4) colour image, got shape "
                         f"{np.asarray(image).shape}")
    return img


def detect_sift(image, contrast_threshold: float = CONTRAST_THRESHOLD, edge_threshold: float = EDGE_THRESHOLD,
                n_octave_layers: int = 3, max_features: int = 0, mask=None, *, channel_order: str | None = None
                ) -> Features:
    """SIFT keypoints and descriptors of an 8-bit image (section 3.4).

    Parameters
    ----------
    image : ndarray (H, W) or (H, W, 3|4) uint8, or a path (str or os.PathLike)
        A grey image; a colour image with its ``channel_order``; or an image file, read by OpenCV.
    contrast_threshold : float
        Lowe's DoG threshold for an image scaled to [0, 1] (thesis: 0.03); mapped to OpenCV's convention here.
    edge_threshold : float
        Principal-curvature ratio r (thesis: 10, Eq. 105).
    n_octave_layers : int
    max_features : int
        Keep the strongest ``max_features`` (0 = all).
    mask : ndarray (H, W) uint8, optional
        Detect only where non-zero.
    channel_order : {"rgb", "bgr"}, optional
        Required for a 3- or 4-channel array (``cv2.imread`` gives ``"bgr"``; the bench's renderer and
        :meth:`bench.dataset.View.image` give ``"rgb"``); ignored for a grey array; refused with a path. A colour
        array without it is a ``ValueError``: the grey levels SIFT detects on depend on it.

    Returns
    -------
    Features
    """
    grey = _grey(image, channel_order)
    if not (contrast_threshold > 0 and edge_threshold > 1):
        raise ValueError(f"contrast_threshold must be > 0 and edge_threshold > 1, got {contrast_threshold}, "
                         f"{edge_threshold}")
    # enable_precise_upscale: OpenCV's default doubling of the image for octave -1 maps pixel x to 2x + 0.5 and puts
    # every keypoint 0.25 px right and below its feature (measured: 0.249 / 0.252 px on Gaussian blobs, 0.002 with it)
    sift = cv2.SIFT_create(nfeatures=int(max_features), nOctaveLayers=int(n_octave_layers),
                           contrastThreshold=float(contrast_threshold) * n_octave_layers,
                           edgeThreshold=float(edge_threshold), enable_precise_upscale=True)
    kps, desc = sift.detectAndCompute(grey, mask)
    if not kps:
        return Features(np.empty((0, 2)), np.empty(0), np.empty(0), np.empty(0), np.empty((0, 128), np.float32))
    uv = np.array([k.pt for k in kps], dtype=float)
    angle = -np.array([k.angle for k in kps], dtype=float)  # OpenCV: clockwise on screen in [0, 360)
    angle = (angle + 180.0) % 360.0 - 180.0
    angle[angle == -180.0] = 180.0
    return Features(uv, angle, np.array([k.size for k in kps], dtype=float),
                    np.array([k.response for k in kps], dtype=float), np.asarray(desc, dtype=np.float32))


def match_descriptors(f1: Features, f2: Features, ratio: float = RATIO, mutual: bool = False) -> Matches:
    """Nearest-neighbour matches passing Lowe's ratio test (section 3.4.7).

    Parameters
    ----------
    f1, f2 : Features
    ratio : float
        Reject when ``d_nearest > ratio * d_second`` (thesis: 0.8).
    mutual : bool
        Also require ``f1[i1]`` to be the nearest neighbour of ``f2[i2]``.
    """
    if not 0 < ratio <= 1:
        raise ValueError(f"ratio: must be in (0, 1], got {ratio}")
    empty = Matches(np.empty(0, int), np.empty(0, int), np.empty(0), np.empty(0))
    if len(f1) == 0 or len(f2) < 2:
        return empty
    bf = cv2.BFMatcher(cv2.NORM_L2)
    knn = bf.knnMatch(f1.descriptors, f2.descriptors, k=2)
    i1, i2, d, r = [], [], [], []
    for pair in knn:
        if len(pair) < 2:
            continue
        m, n = pair
        if m.distance <= ratio * n.distance:
            i1.append(m.queryIdx)
            i2.append(m.trainIdx)
            d.append(m.distance)
            r.append(m.distance / n.distance if n.distance > 0 else 0.0)
    if not i1:
        return empty
    out = Matches(np.array(i1), np.array(i2), np.array(d), np.array(r))
    return _mutual(f1, f2, out) if mutual else out


def _mutual(f1: Features, f2: Features, matches: Matches) -> Matches:
    """The matches whose ``f1`` keypoint is also the nearest neighbour of their ``f2`` keypoint (cross-check)."""
    if len(matches) == 0:
        return matches
    back = cv2.BFMatcher(cv2.NORM_L2).match(f2.descriptors, f1.descriptors)
    nn21 = np.full(len(f2), -1)
    for m in back:
        nn21[m.queryIdx] = m.trainIdx
    return matches.subset(nn21[matches.i2] == matches.i1)


def orientation_difference(theta1_deg, theta2_deg):
    """Eq. 106: ``theta1 - theta2`` wrapped to (-180, 180] deg (the candidate of smallest magnitude)."""
    d = np.asarray(theta1_deg, dtype=float) - np.asarray(theta2_deg, dtype=float)
    cand = np.stack([d - 360.0, d, d + 360.0])
    return np.take_along_axis(cand, np.argmin(np.abs(cand), axis=0)[None], axis=0)[0]


def prevailing_orientation_change(dtheta_deg, bin_deg: float = 10.0) -> float:
    """The peak of the circular histogram of orientation changes (Figure 28), refined by the circular mean of the
    changes within one bin of the peak; deg."""
    d = np.asarray(dtheta_deg, dtype=float)
    if d.size == 0:
        raise ValueError("dtheta_deg: no matches")
    edges = np.arange(-180.0, 180.0 + bin_deg, bin_deg)
    hist, _ = np.histogram(d, bins=edges)
    peak = 0.5 * (edges[np.argmax(hist)] + edges[np.argmax(hist) + 1])
    near = d[np.abs(orientation_difference(d, peak)) <= bin_deg]
    return float(np.rad2deg(np.angle(np.mean(np.exp(1j * np.deg2rad(near))))))


def orientation_filter(f1: Features, f2: Features, matches: Matches, tol_deg: float = ORIENTATION_TOL_DEG,
                       expected_deg: float | None = None):
    """Keep matches whose orientation change is within ``tol_deg`` of the prevailing one (section 3.4.7, Eq. 106).

    Parameters
    ----------
    expected_deg : float, optional
        The expected in-plane rotation between the views (e.g. from the arm's kinematics); default the histogram peak.

    Returns
    -------
    (Matches, float)
        The kept matches and the orientation change used as centre (deg).
    """
    if len(matches) == 0:
        return matches, float("nan")
    d = orientation_difference(f1.angle_deg[matches.i1], f2.angle_deg[matches.i2])
    centre = prevailing_orientation_change(d) if expected_deg is None else float(expected_deg)
    keep = np.abs(orientation_difference(d, centre)) <= tol_deg
    return matches.subset(keep), centre


@dataclass(frozen=True)
class MatchResult:
    """Matches between two images after the ratio test and the orientation filter (:func:`match_features`).

    Attributes
    ----------
    features1, features2 : Features
        All keypoints of image 1 and image 2.
    i1, i2 : ndarray (M,) int
        Indices of the kept matches in ``features1`` / ``features2``.
    distance : ndarray (M,)
        Descriptor distance of each match (L2, SIFT descriptor units).
    ratio : ndarray (M,)
        Nearest / second-nearest descriptor distance (the ratio test keeps <= 0.8).
    orientation_change_deg : ndarray (M,)
        Keypoint-orientation change of each match, Eq. 106 (deg, in (-180, 180]).
    orientation_centre_deg : float
        The prevailing orientation change the filter was centred on (the histogram peak of Figure 28, or the
        ``expected_deg`` given); NaN when nothing passed the ratio test.
    counts : dict
        Counts at each stage, in order: ``keypoints1``, ``keypoints2``, ``ratio_test``, ``mutual`` (only when the
        cross-check was asked for), ``orientation_filter`` (= M).
    """

    features1: Features
    features2: Features
    i1: np.ndarray
    i2: np.ndarray
    distance: np.ndarray
    ratio: np.ndarray
    orientation_change_deg: np.ndarray
    orientation_centre_deg: float
    counts: dict

    def __len__(self) -> int:
        return len(self.i1)

    @property
    def uv1(self) -> np.ndarray:
        """Pixels (M, 2) of the matches in image 1 (OpenCV convention, as detected)."""
        return self.features1.uv[self.i1]

    @property
    def uv2(self) -> np.ndarray:
        """Pixels (M, 2) of the matches in image 2."""
        return self.features2.uv[self.i2]

    @property
    def matches(self) -> Matches:
        """The kept matches as a :class:`Matches` (what :mod:`bench.vision.insitu` consumes)."""
        return Matches(self.i1, self.i2, self.distance, self.ratio)


def match_features(f1: Features, f2: Features, ratio: float = RATIO, orientation_tol_deg: float = ORIENTATION_TOL_DEG,
                   expected_deg: float | None = None, mutual: bool = False) -> MatchResult:
    """Match two keypoint sets: Lowe's ratio test, then the orientation filter (thesis section 3.4.7, Eq. 106).

    Parameters
    ----------
    f1, f2 : Features
    ratio : float
        Reject a match when the nearest descriptor is farther than ``ratio`` times the second nearest (thesis:
        0.8, section 3.4.7).
    orientation_tol_deg : float
        Keep matches whose orientation change (Eq. 106) is within this of the prevailing change (thesis: 20 deg,
        Lowe's suggestion in section 3.4.7; the peak of Figure 28's histogram).
    expected_deg : float, optional
        Centre the orientation filter on this in-plane rotation (deg, e.g. from the arm's kinematics) instead of the
        histogram peak.
    mutual : bool
        Also require the match to be the nearest neighbour in the other direction (not in the thesis; default off).

    Returns
    -------
    MatchResult
    """
    if not (np.isfinite(orientation_tol_deg) and 0 < orientation_tol_deg <= 180):
        raise ValueError(f"orientation_tol_deg: expected a tolerance in (0, 180] deg, got {orientation_tol_deg}")
    m = match_descriptors(f1, f2, ratio)
    counts = {"keypoints1": len(f1), "keypoints2": len(f2), "ratio_test": len(m)}
    if mutual:
        m = _mutual(f1, f2, m)
        counts["mutual"] = len(m)
    kept, centre = orientation_filter(f1, f2, m, orientation_tol_deg, expected_deg)
    counts["orientation_filter"] = len(kept)
    change = orientation_difference(f1.angle_deg[kept.i1], f2.angle_deg[kept.i2])
    return MatchResult(f1, f2, kept.i1, kept.i2, kept.distance, kept.ratio, change, centre, counts)


def match_images(image1, image2, *, channel_order: str | None = None, ratio: float = RATIO,
                 orientation_tol_deg: float = ORIENTATION_TOL_DEG, expected_deg: float | None = None,
                 mutual: bool = False, max_features: int = 0, mask1=None, mask2=None) -> MatchResult:
    """Match two images: SIFT (:func:`detect_sift`, thesis thresholds), then :func:`match_features` (ratio test 0.8 and
    orientation filter +-20 deg, section 3.4.7, Eq. 106).

    Parameters
    ----------
    image1, image2 : ndarray (H, W) or (H, W, 3|4) uint8, or paths
        Grey arrays, colour arrays with ``channel_order``, or image files (see :func:`detect_sift`).
    channel_order : {"rgb", "bgr"}, optional
        Channel order of colour arrays (both images); required for them, not used for files.
    ratio, orientation_tol_deg, expected_deg, mutual
        See :func:`match_features`.
    max_features : int
        Keep the strongest ``max_features`` keypoints of each image (0 = all).
    mask1, mask2 : ndarray (H, W) uint8, optional
        Detect only where non-zero.

    Returns
    -------
    MatchResult
        ``uv1``, ``uv2`` are the matched pixels (as detected: undistort them with the camera model before
        triangulating, or use :func:`bench.vision.triangulation.triangulate_pixels`).
    """
    def order(image):  # an image file knows its own channel order
        return None if isinstance(image, (str, os.PathLike)) else channel_order

    f1 = detect_sift(image1, max_features=max_features, mask=mask1, channel_order=order(image1))
    f2 = detect_sift(image2, max_features=max_features, mask=mask2, channel_order=order(image2))
    return match_features(f1, f2, ratio, orientation_tol_deg, expected_deg, mutual)
