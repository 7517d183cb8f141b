"""How a camera errs, from photos of a planar chessboard: detection, calibration and the residuals' statistics.

One piece of code for real photos and for their simulation (the ``camera_replica`` scenario kind,
``tools/real_camera_stats.py``), so the two are compared like with like:

* :func:`detect_views` - ``cv2.findChessboardCornersSB`` with ``CALIB_CB_ACCURACY`` on every photo;
* :func:`calibrate_views` - the bench's calibration (Heikkilä by default) on unit squares;
* :func:`residual_statistics` - RMS, per-view spread, and the correlation of residual vectors along a board row or
  column (the statistic issue 12 compares);
* :func:`measure_sift_precision` - SIFT's localisation noise on the board plane.

Reads only images; no simulator truth.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from bench.camera.corners import CV_RNG_SEED


class BoardView(NamedTuple):
    """A photo where the board was found: its file, colour image (RGB or grey), grey image and corners ``(N, 2)``
    (px, OpenCV's order: ``pattern[0]`` corners per row)."""

    path: Path
    image: np.ndarray
    grey: np.ndarray
    uv: np.ndarray


def detect_board(grey, pattern):
    """The ``pattern = (cols, rows)`` inner corners ``(cols * rows, 2)`` (px) of a chessboard in a grey ``uint8``
    image, or None. ``findChessboardCornersSB`` with ``CALIB_CB_ACCURACY``, OpenCV's RNG seeded first (the detector
    draws from it: :data:`bench.camera.corners.CV_RNG_SEED`)."""
    cv2.setRNGSeed(CV_RNG_SEED)
    ok, c = cv2.findChessboardCornersSB(grey, tuple(int(v) for v in pattern), flags=cv2.CALIB_CB_ACCURACY)
    return c.reshape(-1, 2).astype(float) if ok else None


def detect_views(files, pattern, read=None) -> list:
    """:class:`BoardView` of each photo in ``files`` where the board is found (the others are left out).

    ``read(path)``: the image decoder (default :func:`bench.dataset.read_image`: Pillow, a one-line error naming a
    file it cannot decode)."""
    if read is None:
        from bench.dataset import read_image as read
    out = []
    for f in files:
        img = read(Path(f))
        grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        uv = detect_board(grey, pattern)
        if uv is not None:
            out.append(BoardView(Path(f), img, grey, uv))
    return out


def board_points(pattern) -> np.ndarray:
    """The board's inner corners ``(cols * rows, 3)`` in unit squares, OpenCV's order (x along a row, z = 0)."""
    cols, rows = pattern
    obj = np.zeros((cols * rows, 3))
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2)
    return obj


def calibrate_views(views, pattern, model: str = "heikkila"):
    """The bench's calibration (:func:`bench.camera.calibration.calibrate_camera`) of the detected views, the board
    in unit squares (its ``T_cam_target`` translations are then in squares)."""
    from bench.camera import calibration as cal

    uvs = [v.uv for v in views]
    return cal.calibrate_camera([board_points(pattern)] * len(uvs), uvs, views[0].grey.shape[::-1], model)


def residual_statistics(residuals, pattern, uvs=None, max_lag: int = 3) -> dict:
    """Spatial structure of calibration residuals of chessboard views.

    Parameters
    ----------
    residuals : list of ndarray (N, 2)
        Per view, the residual of each corner (px), corners row-major with ``pattern = (cols, rows)``.
    uvs : list of ndarray (N, 2), optional
        The detected corners (px), for the cross-view image-distance correlation.

    Returns
    -------
    dict
        ``rms_px`` (all corners), ``per_view_rms_px`` (list), ``per_view_rms_cv`` (std / mean of the per-view RMS),
        ``row_corr_lag{k}`` and ``col_corr_lag{k}``: the normalised correlation of residual *vectors* k corners apart
        along a board row (column), pooled over views,
        ``rho_k = sum(r_i . r_{i+k}) / sqrt(sum |r_i|^2 sum |r_{i+k}|^2)``
        (0 for white noise, 1 for a common shift); ``cross_view_corr_{a}_{b}px``: the same correlation for corner
        pairs of *different* views whose image positions lie a..b px apart (residual tied to the image).
    """
    cols, rows = pattern
    R = [np.asarray(r, float).reshape(rows, cols, 2) for r in residuals]
    allr = np.concatenate([r.reshape(-1, 2) for r in R])
    pv = np.array([np.sqrt(np.mean(np.sum(r ** 2, -1))) for r in R])
    out = {"rms_px": float(np.sqrt(np.mean(np.sum(allr ** 2, 1)))), "per_view_rms_px": pv.round(4).tolist(),
           "per_view_rms_cv": float(pv.std() / pv.mean())}
    for name, axis in (("row", 1), ("col", 0)):
        for k in range(1, max_lag + 1):
            a = np.concatenate([(r[:, :-k] if axis == 1 else r[:-k]).reshape(-1, 2) for r in R])
            b = np.concatenate([(r[:, k:] if axis == 1 else r[k:]).reshape(-1, 2) for r in R])
            den = np.sqrt(np.sum(a * a) * np.sum(b * b))
            out[f"{name}_corr_lag{k}"] = float(np.sum(a * b) / den) if den > 0 else float("nan")
    if uvs is not None:
        P = [np.asarray(u, float) for u in uvs]
        Rf = [r.reshape(-1, 2) for r in R]
        for lo, hi in ((0, 20), (20, 60), (60, 150)):
            num = den_a = den_b = 0.0
            for i in range(len(P)):
                for j in range(i + 1, len(P)):
                    d = np.linalg.norm(P[i][:, None] - P[j][None], axis=-1)
                    ii, jj = np.nonzero((d >= lo) & (d < hi))
                    num += np.sum(Rf[i][ii] * Rf[j][jj])
                    den_a += np.sum(Rf[i][ii] ** 2)
                    den_b += np.sum(Rf[j][jj] ** 2)
            out[f"cross_view_corr_{lo}_{hi}px"] = float(num / np.sqrt(den_a * den_b)) if den_a > 0 else float("nan")
    return out


def board_homography(corners, pattern):
    """The homography from the board's unit-square grid to the detected ``corners`` ``(N, 2)``."""
    cols, rows = pattern
    g = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), -1).reshape(-1, 2).astype(np.float32)
    H, _ = cv2.findHomography(g, corners.astype(np.float32))
    return H


def apply_homography(H, pts):
    """Points ``(N, 2)`` mapped by ``H`` (float32, as ``cv2.perspectiveTransform``)."""
    return cv2.perspectiveTransform(np.asarray(pts, np.float32).reshape(-1, 1, 2), H).reshape(-1, 2)


def measure_sift_precision(views, pattern, K, dist, ratio: float = 0.8, inlier_px: float = 1.5) -> dict:
    """SIFT's localisation noise on the board, from the photos themselves (px, per keypoint and image axis).

    The board is a plane: between two views its SIFT keypoints (inside the board's outline, found from the detected
    corners) are related by a homography once the lens distortion is removed (``K``, ``dist``: OpenCV's order). Every
    pair of views is matched (:func:`bench.vision.features.match_descriptors`: Lowe's ratio, cross-checked), a
    homography fitted by RANSAC (``inlier_px``) and refitted to its inliers; the robust standard deviation (1.4826 MAD)
    of all pairs' transfer residuals, divided by sqrt(2) (both keypoints are noisy), is the keypoint noise. The board's
    own unflatness (a few tenths of a millimetre) is in it, for the real photos and their simulation alike, so the
    figure is for comparing the two, not a detector's noise in isolation."""
    from bench.vision.features import detect_sift, match_descriptors

    K, dist = np.asarray(K, float), np.asarray(dist, float)
    cols, rows = pattern
    feats = []
    for v in views:
        H = board_homography(v.uv, pattern)
        quad = apply_homography(H, [[-0.8, -0.8], [cols - 0.2, -0.8], [cols - 0.2, rows - 0.2], [-0.8, rows - 0.2]])
        mask = np.zeros(v.grey.shape, np.uint8)
        cv2.fillConvexPoly(mask, np.round(quad).astype(np.int32), 255)
        f = detect_sift(v.grey, mask=mask)
        x = cv2.undistortPoints(f.uv.reshape(-1, 1, 2).astype(np.float64), K, dist, P=K).reshape(-1, 2)
        feats.append((f, x))
    residuals, pairs = [], 0
    for i in range(len(feats)):
        for j in range(i + 1, len(feats)):
            (fi, xi), (fj, xj) = feats[i], feats[j]
            m = match_descriptors(fi, fj, ratio, mutual=True)
            if len(m) < 12:
                continue
            a, b = xi[m.i1], xj[m.i2]
            H, inl = cv2.findHomography(a, b, cv2.RANSAC, inlier_px)
            if H is None or inl.sum() < 12:
                continue
            inl = inl.ravel().astype(bool)
            H, _ = cv2.findHomography(a[inl], b[inl], 0)
            residuals.append(apply_homography(H, a[inl]) - b[inl])
            pairs += 1
    if not residuals:
        return {"sift_plane_px": float("nan"), "sift_plane_pairs": 0, "sift_plane_matches": 0}
    r = np.concatenate(residuals)
    mad = 1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0)
    return {"sift_plane_px": float(np.mean(mad) / np.sqrt(2)), "sift_plane_pairs": pairs,
            "sift_plane_matches": int(len(r))}
