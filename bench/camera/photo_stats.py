"""How a camera errs, from photos of a planar chessboard: detection, calibration and the residuals' statistics.

One piece of code for real photos and for their simulation (the ``camera_replica`` scenario kind,
``tools/real_camera_stats.py``), so the two are compared like with like:

* :func:`detect_views` - ``cv2.findChessboardCornersSB`` with ``CALIB_CB_ACCURACY`` on every photo;
* :func:`calibrate_views` - the bench's calibration (Heikkilä by default) on unit squares;
* :func:`residual_statistics` - RMS, per-view spread, and the correlation of residual vectors along a board row or
  column (the statistic issue 12 compares);
* :func:`measure_sift_precision` - SIFT's localisation noise on the board plane;
* :func:`measure_noise`, :func:`measure_blur`, :func:`measure_edge_profile` - the images themselves: noise and
  level in the squares, the edge spread, and the shape of an edge (a sharpening halo).

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


def photo_paths(folder) -> list:
    """The photos in ``folder`` as paths (:func:`bench.dataset.photo_files`: ``.png``, ``.jpg``, ``.jpeg`` in any
    letter case, sorted by name); ``ValueError`` (one line naming the folder) when it is not a folder or holds none."""
    from bench.dataset import IMAGE_SUFFIXES, photo_files

    if not Path(folder).is_dir():
        raise ValueError(f"{folder}: not a folder")
    files = [str(f) for f in photo_files(Path(folder))]
    if not files:
        raise ValueError(f"{folder}: no photos (files ending {', '.join(IMAGE_SUFFIXES)}, any case)")
    return files


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


def parse_pattern(text: str) -> tuple:
    """``"7x7"`` -> ``(7, 7)``: a board's inner corners per row x per column; ValueError naming the text otherwise."""
    try:
        pattern = tuple(int(v) for v in str(text).lower().split("x"))
    except ValueError:
        pattern = ()
    if len(pattern) != 2 or min(pattern) < 2:
        raise ValueError(f"expected e.g. 7x7 (inner corners), got {text!r}")
    return pattern


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


def measure_noise(views, pattern) -> dict:
    """Std (DN, grey) inside square interiors after a plane fit; white and black squares; JPEG leaves what it keeps.

    The squares fully inside the inner-corner grid are used (grid cells (i, j) .. (i+1, j+1)); the central 40 % of
    each square's width is sampled; the colour of a cell is decided by its mean (the board's parity is unknown)."""
    stats = {"white": [], "black": []}
    means = {"white": [], "black": []}
    cols, rows = pattern
    for _, _, grey, c in views:
        H = board_homography(c, pattern)
        for i in range(rows - 1):
            for j in range(cols - 1):
                s = np.linspace(0.3, 0.7, 9)
                gx, gy = np.meshgrid(j + s, i + s)
                p = apply_homography(H, np.c_[gx.ravel(), gy.ravel()])
                u0, v0 = np.floor(p.min(0)).astype(int)
                u1, v1 = np.ceil(p.max(0)).astype(int)
                if u1 - u0 < 4 or v1 - v0 < 4:
                    continue
                # pixels inside the central quadrilateral
                quad = apply_homography(H, [[j + 0.3, i + 0.3], [j + 0.7, i + 0.3], [j + 0.7, i + 0.7],
                                            [j + 0.3, i + 0.7]])
                mask = np.zeros(grey.shape, np.uint8)
                cv2.fillConvexPoly(mask, np.round(quad).astype(np.int32), 1)
                vv, uu = np.nonzero(mask)
                if len(vv) < 20:
                    continue
                val = grey[vv, uu].astype(float)
                A = np.c_[uu, vv, np.ones_like(uu)].astype(float)
                res = val - A @ np.linalg.lstsq(A, val, rcond=None)[0]
                kind = "white" if val.mean() > 128 else "black"
                stats[kind].append(res.std(ddof=3))
                means[kind].append(val.mean())
    return {f"noise_{k}_dn": float(np.median(v)) for k, v in stats.items() if v} | \
           {f"level_{k}_dn": float(np.median(v)) for k, v in means.items() if v}


def _erf_fit(x, y):
    """Fit ``a + b erf((x - x0) / (sqrt(2) sigma))``; returns sigma (px) or None."""
    from scipy.optimize import least_squares
    from scipy.special import erf

    a0, b0 = (y.max() + y.min()) / 2, (y[-1] - y[0]) / 2
    if abs(b0) < 20:
        return None

    def f(p):
        return p[0] + p[1] * erf((x - p[2]) / (np.sqrt(2) * abs(p[3]) + 1e-9)) - y

    r = least_squares(f, [a0, b0, 0.0, 1.0])
    if not r.success or abs(r.x[2]) > 2 or not 0.1 < abs(r.x[3]) < 5:
        return None
    return abs(r.x[3])


def edge_profiles(views, pattern, t, fractions):
    """Grey profiles (DN) across every square edge between neighbouring inner corners: for each edge and each
    fraction of its length in ``fractions``, the image sampled bilinearly at distances ``t`` (px) along the edge's
    normal. Yields ``(len(t),)`` arrays."""
    cols, rows = pattern
    for _, _, grey, c in views:
        g = grey.astype(np.float32)
        C = c.reshape(rows, cols, 2)
        pairs = [(C[i, j], C[i, j + 1]) for i in range(rows) for j in range(cols - 1)] + \
                [(C[i, j], C[i + 1, j]) for i in range(rows - 1) for j in range(cols)]
        for a, b in pairs:
            d = b - a
            n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
            for s in fractions:
                p = (a + s * d + t[:, None] * n).astype(np.float32)
                yield cv2.remap(g, p[:, :1], p[:, 1:], cv2.INTER_LINEAR).ravel().astype(float)


def measure_blur(views, pattern) -> dict:
    """Edge spread: erf sigma (px) of profiles across the square edges between neighbouring inner corners (their
    middle half), sampled perpendicular to the edge over +-5 px at 0.25 px (bilinear)."""
    t = np.arange(-5, 5.01, 0.25)
    sig = [r for y in edge_profiles(views, pattern, t, (0.35, 0.5, 0.65)) if (r := _erf_fit(t, y)) is not None]
    sig = np.array(sig)
    return {"edge_sigma_px": float(np.median(sig)), "edge_sigma_p25_px": float(np.percentile(sig, 25)),
            "edge_sigma_p75_px": float(np.percentile(sig, 75)), "edge_profiles": len(sig)}


def median_edge_profile(views, pattern, half_width_px: float = 10.0, step_px: float = 0.5):
    """The median edge profile across the square edges, dark -> bright: ``(t, profile, n)`` with ``t`` the
    distance from the edge (px, every ``step_px`` within +-``half_width_px``), ``profile`` its grey level (DN) and
    ``n`` the profiles used. Each profile is sampled bilinearly every 0.25 px across the middle of an edge between
    neighbouring inner corners (at 0.4, 0.5 and 0.6 of it) and aligned at its mid-level crossing; profiles with
    less than 60 DN of contrast or more than one crossing (noise, a neighbouring edge) are left out."""
    t = np.arange(-half_width_px - 2, half_width_px + 2.01, 0.25)
    tt = np.arange(-half_width_px, half_width_px + step_px / 2, step_px)
    profiles = []
    for y in edge_profiles(views, pattern, t, (0.4, 0.5, 0.6)):
        if y[-1] < y[0]:
            y = y[::-1]
        lo, hi = np.median(y[:5]), np.median(y[-5:])
        if hi - lo < 60:
            continue
        mid = (lo + hi) / 2
        k = np.nonzero((y[:-1] < mid) & (y[1:] >= mid))[0]
        if len(k) != 1:
            continue
        k = k[0]
        x0 = t[k] + (mid - y[k]) / (y[k + 1] - y[k]) * (t[1] - t[0])
        profiles.append(np.interp(tt + x0, t, y))
    return tt, np.median(np.array(profiles), axis=0), len(profiles)


def measure_edge_profile(views, pattern) -> dict:
    """How a camera's processing shapes an edge (:func:`median_edge_profile`): ``edge_undershoot_dn``, how far the
    median profile dips below the black squares' level beside the edge (a sharpening halo; 0 for an unsharpened
    camera), and ``edge_width_10_90_px``, its 10-90 % rise distance."""
    tt, med, n = median_edge_profile(views, pattern)
    lo, hi = med[0], med[-1]
    rise = (med - lo) / (hi - lo)
    width = np.interp(0.9, rise, tt) - np.interp(0.1, rise, tt)  # the median profile rises monotonically in between
    return {"edge_undershoot_dn": float(lo - med[:len(tt) // 2].min()), "edge_width_10_90_px": float(width),
            "edge_profiles_used": n}
