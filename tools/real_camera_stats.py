"""Measure how a real camera errs, from photos of a chessboard: the evidence behind ``imaging: realistic``.

    .venv/bin/python tools/real_camera_stats.py [--data DIR] [--pattern 7x7] [--json OUT.json]

``DIR`` holds JPEG/PNG photos of a chessboard with ``--pattern`` inner corners (default the project's real webcam
photos, ``tests/data/real_webcam_chessboard``: 19 views, 640 x 480, 7 x 7 inner corners). Every statistic is
defined in :mod:`bench.camera.photo_stats` (detection, calibration, :func:`residual_statistics`, SIFT) and the
``measure_*`` functions here; docs/realistic_imaging.md quotes this tool's output. The ``camera_replica`` scenario
kind computes the same statistics for the photos and their simulation, with the same code.

Measured here:

* calibration (``cv2.findChessboardCornersSB`` with the ACCURACY flag, the bench's Heikkilä calibration): RMS and
  per-view RMS (px); and the radial-only (k1 k2) fit, the simulated webcam's true lens (``radial_*``);
* residual correlation along a board row / column at lag k (:func:`residual_statistics`) and across views at
  image distance d (the part of the residual tied to the image, i.e. the lens, not the board);
* JPEG quality: the file's quantisation tables (DQT) matched to the IJG tables scaled for quality 1..100;
* noise in flat regions: the standard deviation (DN) inside white and black squares after removing a plane;
* blur: the edge spread function across square edges, fitted by an erf: its Gaussian sigma (px);
* vignetting: white-square brightness against the distance from the image centre (``I = I0 (1 - a r^2)``, r in
  units of the half diagonal) - lighting contributes too, so this is an upper bound on the lens's vignetting;
* lateral chromatic aberration: corners located in R and in B separately (``cv2.cornerSubPix``) minus G, radial
  component against radius: ``d_r = c r`` (c in px per 1000 px of radius);
* the board's shape (:func:`measure_board_shape`): the 3-D position of every printed corner, common to all views,
  estimated with the camera (OpenCV's release-object calibration, Strobl & Hirzinger, ICCV Workshops 2011); the
  residual's direction against the image direction in which an out-of-plane displacement moves each corner; the
  shape's quadratic bow and its rougher rest (cockle), whose Gaussian-covariance amplitude and correlation lengths
  along and across the board rows are fitted by restricted maximum likelihood; the in-plane line offsets; the
  residual left per view.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.camera.calibration import opencv_one_thread  # noqa: E402
from bench.camera.photo_stats import (  # noqa: E402 - detection, calibration, residual and image statistics
    apply_homography,
    board_homography,
    calibrate_views,
    detect_views,
    measure_blur,
    measure_edge_profile,
    measure_noise,
    measure_sift_precision,
    parse_pattern,
    photo_paths,
    residual_statistics,
)

DEFAULT_DATA = ROOT / "tests" / "data" / "real_webcam_chessboard"


def calibrate(views, pattern, model="heikkila"):
    """The bench's calibration of the detected views (unit squares): ``(result, uvs)``."""
    return calibrate_views(views, pattern, model), [v.uv for v in views]

#: IJG (libjpeg) standard luminance quantisation table (ITU-T T.81 Annex K, Table K.1); its sum is order-free
IJG_LUMA = np.array([16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
                     14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
                     49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99])


def ijg_table(quality: int) -> np.ndarray:
    """IJG luminance quantisation table (64,) at ``quality`` 1..100 (libjpeg's ``jpeg_quality_scaling``)."""
    q = int(quality)
    scale = 5000 // q if q < 50 else 200 - 2 * q
    return np.clip((IJG_LUMA * scale + 50) // 100, 1, 255)


def jpeg_luma_table(data: bytes) -> np.ndarray | None:
    """The luminance quantisation table (64,) of a JPEG file (table 0 of its DQT segments, read by Pillow), or None."""
    from PIL import Image

    tables = getattr(Image.open(io.BytesIO(data)), "quantization", None) or {}
    return np.array(tables[0], dtype=int) if 0 in tables else None


def estimate_jpeg_quality(data: bytes) -> tuple:
    """``(quality, exact)``: the IJG quality whose luminance table matches the file's (same multiset of values:
    exact=True), else the quality with the nearest table sum."""
    table = jpeg_luma_table(data)
    if table is None:
        return None, False
    best, best_d = None, np.inf
    for q in range(1, 101):
        t = ijg_table(q)
        if np.array_equal(np.sort(t), np.sort(table)):
            return q, True
        d = abs(int(t.sum()) - int(table.sum()))
        if d < best_d:
            best, best_d = q, d
    return best, False


def measure_vignetting(views, pattern) -> dict:
    """Fit ``I = I0 (1 - a r^2)`` to the white squares' centre brightness (r: distance from the image centre over
    the half diagonal); returns ``a`` (fall-off at the corner, fraction) per view's median and all pooled."""
    cols, rows = pattern
    rr, ii = [], []
    for _, _, grey, c in views:
        h, w = grey.shape
        H = board_homography(c, pattern)
        ctr = np.array([(j + 0.5, i + 0.5) for i in range(rows - 1) for j in range(cols - 1)])
        p = apply_homography(H, ctr)
        vals = np.array([cv2.getRectSubPix(grey, (5, 5), tuple(map(float, q))).mean() for q in p])
        white = vals > np.median(vals)
        r = np.linalg.norm(p - [(w - 1) / 2, (h - 1) / 2], axis=1) / np.hypot(w / 2, h / 2)
        rr.append(r[white])
        ii.append(vals[white] / vals[white].mean())
    r, i = np.concatenate(rr), np.concatenate(ii)
    A = np.c_[np.ones_like(r), -r ** 2]
    coef = np.linalg.lstsq(A, i, rcond=None)[0]
    return {"vignetting_a_corner": float(coef[1] / coef[0]), "white_brightness_cv": float(i.std())}


def measure_chromatic(views, pattern) -> dict:
    """Lateral chromatic aberration: corners refined in R and B alone minus G, radial component vs radius."""
    rad, dr_r, dr_b = [], [], []
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    for _, rgb, _, c in views:
        h, w = rgb.shape[:2]
        ctr = np.array([(w - 1) / 2, (h - 1) / 2])
        loc = {}
        for k, ch in (("r", 0), ("g", 1), ("b", 2)):  # the photos as read_image decodes them: RGB
            p = c.astype(np.float32).reshape(-1, 1, 2).copy()
            loc[k] = cv2.cornerSubPix(np.ascontiguousarray(rgb[..., ch]), p, (5, 5), (-1, -1), crit).reshape(-1, 2)
        v = loc["g"] - ctr
        r = np.linalg.norm(v, axis=1)
        e = v / np.maximum(r, 1e-9)[:, None]
        rad.append(r)
        dr_r.append(np.sum((loc["r"] - loc["g"]) * e, 1))
        dr_b.append(np.sum((loc["b"] - loc["g"]) * e, 1))
    r = np.concatenate(rad)
    out = {}
    for k, d in (("r", np.concatenate(dr_r)), ("b", np.concatenate(dr_b))):
        A = np.c_[np.ones_like(r), r]
        coef = np.linalg.lstsq(A, d, rcond=None)[0]
        out[f"lateral_ca_{k}_px_per_1000px"] = float(coef[1] * 1000)
        out[f"lateral_ca_{k}_offset_px"] = float(coef[0])
    return out


def measure_board_bow(res, uvs, pattern, square_mm: float) -> dict:
    """How far the real board is from a plane: per view, the pose and a quadratic out-of-plane shape
    ``z = a x^2 + b y^2 + c x y`` (board coordinates centred on the board, in squares) fitted to the corners with
    the calibration's intrinsics and distortion held; the sagitta is ``max |z| - min |z|`` over the corner grid in mm
    (for a square of ``square_mm``) and the residual RMS left after the shape (px)."""
    from scipy.optimize import least_squares

    cols, rows = pattern
    g = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(float)
    gc = g - g.mean(0)
    K, dist = res.camera.K, res.camera.dist
    sag, rms_after, rms_before = [], [], []
    for uv in uvs:
        obj0 = np.c_[g, np.zeros(len(g))]
        _, rvec, tvec = cv2.solvePnP(obj0, uv, K, dist)

        def f(p, uv=uv):
            z = p[6] * gc[:, 0] ** 2 + p[7] * gc[:, 1] ** 2 + p[8] * gc[:, 0] * gc[:, 1]
            proj, _ = cv2.projectPoints(np.c_[g, z], p[:3], p[3:6], K, dist)
            return (proj.reshape(-1, 2) - uv).ravel()

        p0 = np.r_[rvec.ravel(), tvec.ravel(), 0.0, 0.0, 0.0]
        r0 = least_squares(f, np.r_[rvec.ravel(), tvec.ravel(), 0, 0, 0], x_scale="jac")
        rms_before.append(np.sqrt(np.mean(f(p0) ** 2) * 2))
        p = r0.x
        z = p[6] * gc[:, 0] ** 2 + p[7] * gc[:, 1] ** 2 + p[8] * gc[:, 0] * gc[:, 1]
        sag.append((z.max() - z.min()) * square_mm)
        rms_after.append(np.sqrt(np.mean(r0.fun ** 2) * 2))
    sag = np.array(sag)
    return {"bow_sagitta_median_mm": float(np.median(sag)), "bow_sagitta_max_mm": float(sag.max()),
            "bow_square_mm_assumed": square_mm, "bow_rms_before_px": float(np.sqrt(np.mean(np.square(rms_before)))),
            "bow_rms_after_px": float(np.sqrt(np.mean(np.square(rms_after)))),
            "bow_sagitta_per_view_mm": sag.round(3).tolist()}


def _rotations(pattern):
    """Index maps of the corner grid's four rotations (square grids only: a symmetric board's labellings)."""
    cols, rows = pattern
    idx = np.arange(cols * rows).reshape(rows, cols)
    return [np.rot90(idx, k).ravel() for k in range(4)] if cols == rows else [idx.ravel()]


def measure_print_error(views, pattern, square_mm: float, iterations: int = 4) -> dict:
    """The printed board's line positions, estimated from the photos: the rows and columns of corners are allowed
    their own offsets (in the board plane, along y for a row and x for a column) and the offsets are re-estimated
    from the views' residuals mapped into the board plane (the local homography's inverse Jacobian), alternating
    with the calibration. Each view's corner labelling is first brought to the majority's (a symmetric board's
    detection may start from any of its four corners). The offsets' mean and linear trend are removed (a scale
    and a shift are the pose's). Returns the offsets' RMS in mm (for a square of ``square_mm``) and the
    calibration RMS with the estimated print corrections (what the photos err by when the target's geometry is
    right)."""
    from bench.camera import calibration as cal

    cols, rows = pattern
    g = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(float)
    uvs = [v[3].copy() for v in views]
    size = views[0][2].shape[::-1]

    def calib(off_x, off_y):
        obj = np.c_[g[:, 0] + off_x[g[:, 0].astype(int)], g[:, 1] + off_y[g[:, 1].astype(int)], np.zeros(len(g))]
        return cal.calibrate_camera([obj] * len(uvs), uvs, size, "heikkila"), obj

    res, _ = calib(np.zeros(cols), np.zeros(rows))
    uvs, relabelled = _relabel(res, uvs, pattern)  # calib() reads the relabelled views
    off_x, off_y = np.zeros(cols), np.zeros(rows)
    for _ in range(iterations):
        res, obj = calib(off_x, off_y)
        dX = []
        for r, uv in zip(res.residuals_px, uvs, strict=True):
            H, _ = cv2.findHomography(obj[:, :2], uv - r)  # the fitted projection, locally a homography
            dX.append(_inverse_jacobian_apply(H, obj[:, :2], r))
        dX = np.mean(dX, axis=0)  # board-plane correction of each corner (squares)
        off_x += np.array([dX[g[:, 0] == j, 0].mean() for j in range(cols)])
        off_y += np.array([dX[g[:, 1] == i, 1].mean() for i in range(rows)])
        for o in (off_x, off_y):
            t = np.arange(len(o)) - (len(o) - 1) / 2
            o -= o.mean() + t * np.dot(t, o) / np.dot(t, t)
    res, _ = calib(off_x, off_y)
    return {"print_row_offsets_rms_mm": float(np.sqrt(np.mean(off_y ** 2)) * square_mm),
            "print_col_offsets_rms_mm": float(np.sqrt(np.mean(off_x ** 2)) * square_mm),
            "print_row_offsets_mm": (off_y * square_mm).round(3).tolist(),
            "print_col_offsets_mm": (off_x * square_mm).round(3).tolist(),
            "views_relabelled": relabelled, "rms_with_print_correction_px": float(res.rms_px),
            "per_view_rms_with_print_correction_px": res.per_view_rms_px.round(3).tolist(),
            "residual_stats_with_print_correction": residual_statistics(res.residuals_px, pattern, uvs)}


def _relabel(res, uvs, pattern):
    """Each view's corner labelling brought to view 0's (a symmetric board's detection may start from any of its
    four corners): the labelling whose per-row residual pattern matches view 0's best. Returns the new ``uvs`` and
    how many views were relabelled."""
    cols, rows = pattern
    ref = res.residuals_px[0].reshape(rows, cols, 2)[..., 1].mean(1)
    out, relabelled = [uvs[0].copy()], 0
    for k in range(1, len(uvs)):
        best = max(_rotations(pattern), key=lambda m, k=k: float(np.dot(
            res.residuals_px[k][m].reshape(rows, cols, 2)[..., 1].mean(1), ref)))
        relabelled += not np.array_equal(best, np.arange(cols * rows))
        out.append(uvs[k][best])
    return out, relabelled


def fit_gaussian_field(z, xy, fixed, lengths):
    """Restricted maximum likelihood of a zero-mean Gaussian random field with covariance
    ``s^2 exp(-dx^2 / (2 Lx^2) - dy^2 / (2 Ly^2))`` observed as ``z = fixed @ b + field`` (``fixed`` the columns of
    the trend, e.g. a plane and a quadratic, with its own ``b`` per field): ``(s, Lx, Ly)`` over the grid ``lengths``
    (same unit as ``xy``). ``z``: one field ``(N,)`` or independent realisations ``(R, N)`` at the same points."""
    Q, _ = np.linalg.qr(fixed, mode="complete")
    A = Q[:, fixed.shape[1]:]  # the contrasts free of the trend
    za = np.atleast_2d(z) @ A
    n = za.size
    d = xy[:, None] - xy[None]
    best = None
    for lx in lengths:
        for ly in lengths:
            C = A.T @ (np.exp(-0.5 * (d[..., 0] / lx) ** 2 - 0.5 * (d[..., 1] / ly) ** 2)
                       + 1e-9 * np.eye(len(xy))) @ A
            s2 = np.sum(za * np.linalg.solve(C, za.T).T) / n
            nll = n * np.log(s2) + len(za) * np.linalg.slogdet(C)[1]
            if best is None or nll < best[0]:
                best = (nll, np.sqrt(s2), lx, ly)
    return best[1:]


def measure_board_shape(views, pattern, square_mm: float) -> dict:
    """The real board's shape from the photos themselves.

    1. The residual of the planar calibration against the image direction ``d_i = du_i / dz`` in which an
       out-of-plane displacement of corner i moves it (``normal_energy_fraction``: 0.5 for isotropic errors, 1 if
       all of it is out of plane); the correlation over views of the per-view RMS with ``|d|``.
    2. ``cv2.calibrateCameraRO`` (Strobl & Hirzinger 2011): every corner's 3-D board position, common to all views,
       estimated with the intrinsics and poses (corner ``cols - 1`` fixed besides corner 0: the scale); the shape
       is aligned to the nominal grid by a similarity. Its out-of-plane part (a plane removed) splits into a
       quadratic bow (``quadratic_range_mm``) and the rest, whose Gaussian field's amplitude and correlation lengths
       (along the rows, x; across them, y) are fitted by :func:`fit_gaussian_field`; the in-plane part gives the
       printed lines' offsets (row means of y, column means of x, their mean and linear trend removed).
    3. The calibration RMS with that shape (``rms_with_shape_px``) and the statistics of what is left: the part of
       the residual that differs between views (handling of the board between shots, detection); its share along
       the out-of-plane direction, and the Gaussian field of the per-view out-of-plane offsets (each view's plane
       removed) fitted jointly over the views (``handling_*``).
    """
    cols, rows = pattern
    res, uvs = calibrate(views, pattern)
    uvs, _ = _relabel(res, uvs, pattern)
    res, _ = calibrate([v._replace(uv=u) for v, u in zip(views, uvs, strict=True)], pattern)
    g = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(float)
    obj = np.c_[g, np.zeros(len(g))]
    K, dist = res.camera.K, res.camera.dist
    num = den = 0.0
    pv, sens = [], []
    for T, r in zip(res.T_cam_target, res.residuals_px, strict=True):
        rvec = cv2.Rodrigues(T[:3, :3])[0]

        def proj(P, rvec=rvec, T=T):
            return cv2.projectPoints(P, rvec, T[:3, 3], K, dist)[0].reshape(-1, 2)

        d = (proj(obj + [0, 0, 1e-3]) - proj(obj - [0, 0, 1e-3])) / 2e-3
        n = d / np.linalg.norm(d, axis=1, keepdims=True)
        num += np.sum(np.sum(r * n, 1) ** 2)
        den += np.sum(r ** 2)
        pv.append(np.sqrt(np.mean(np.sum(r ** 2, 1))))
        sens.append(np.median(np.linalg.norm(d, axis=1)) / square_mm)
    size = views[0][2].shape[::-1]
    O = [(obj * square_mm).astype(np.float32)] * len(uvs)
    img = [u.astype(np.float32).reshape(-1, 1, 2) for u in uvs]
    with opencv_one_thread():  # the same figures from run to run (its sums run in parallel otherwise)
        out = cv2.calibrateCameraRO(O, img, size, cols - 1, None, None, flags=cv2.CALIB_FIX_K3)
    rms_ro, shape = float(out[0]), out[5].reshape(-1, 3).astype(float)
    # similarity onto the nominal grid (Umeyama), then the shape's deviations (mm)
    A, B = obj * square_mm, shape
    ma, mb = A.mean(0), B.mean(0)
    U, S, Vt = np.linalg.svd((A - ma).T @ (B - mb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    dev = (np.trace(np.diag(S) @ D) / np.sum((B - mb) ** 2)) * (B - mb) @ R.T + ma - A
    x, y = (g - g.mean(0)).T
    plane, quad = np.c_[np.ones(len(g)), x, y], np.c_[np.ones(len(g)), x, y, x * x, y * y, x * y]
    z = dev[:, 2] - plane @ np.linalg.lstsq(plane, dev[:, 2], rcond=None)[0]
    zq = quad @ np.linalg.lstsq(quad, z, rcond=None)[0]
    s, lx, ly = fit_gaussian_field(z, np.c_[x, y] * square_mm, quad,
                                   np.exp(np.linspace(np.log(0.2), np.log(8.0), 40)) * square_mm)

    def detrended(o):
        t = np.arange(len(o)) - (len(o) - 1) / 2
        o = o - o.mean()
        return o - t * np.dot(t, o) / np.dot(t, t)

    off_y = detrended(dev[:, 1].reshape(rows, cols).mean(1))
    off_x = detrended(dev[:, 0].reshape(rows, cols).mean(0))
    left, flex, num_left = [], [], 0.0
    for rv, tv, u in zip(out[3], out[4], uvs, strict=True):
        def proj(P, rv=rv, tv=tv):
            return cv2.projectPoints(P, rv, tv, out[1], out[2])[0].reshape(-1, 2)

        left.append(u - proj(shape))
        d = (proj(shape + [0, 0, 1e-2]) - proj(shape - [0, 0, 1e-2])) / 2e-2  # px per mm out of plane
        flex.append(np.sum(left[-1] * d, 1) / np.sum(d * d, 1))  # each corner's offset along it (mm)
        num_left += np.sum(np.sum(left[-1] * d, 1) ** 2 / np.sum(d * d, 1))
    # the per-view part (handling): each view's out-of-plane offsets, its plane free (the pose's)
    hs, hx, hy = fit_gaussian_field(np.array(flex), np.c_[x, y] * square_mm, plane,
                                    np.exp(np.linspace(np.log(0.2), np.log(16.0), 40)) * square_mm)
    return {"normal_energy_fraction": float(num / den),
            "per_view_rms_vs_normal_sensitivity_corr": float(np.corrcoef(pv, sens)[0, 1]),
            "shape_out_of_plane_rms_mm": float(np.sqrt(np.mean(z ** 2))),
            "shape_quadratic_range_mm": float(zq.max() - zq.min()),
            "cockle_rms_mm": float(s), "cockle_length_along_rows_mm": float(lx),
            "cockle_length_across_rows_mm": float(ly),
            "shape_print_row_offsets_rms_mm": float(np.sqrt(np.mean(off_y ** 2))),
            "shape_print_col_offsets_rms_mm": float(np.sqrt(np.mean(off_x ** 2))),
            "shape_dz_mm": z.reshape(rows, cols).round(3).tolist(),
            "rms_with_shape_px": rms_ro, "focal_with_shape_px": float(out[1][0, 0]),
            "per_view_normal_energy_fraction": float(num_left / sum(np.sum(r ** 2) for r in left)),
            "handling_rms_mm": float(hs), "handling_length_along_rows_mm": float(hx),
            "handling_length_across_rows_mm": float(hy),
            "residual_stats_with_shape": residual_statistics(left, pattern)}


def _inverse_jacobian_apply(H, XY, duv):
    """Board-plane displacements ``(N, 2)`` whose image under homography ``H`` at ``XY`` is ``duv`` (first order)."""
    out = []
    for (x, y), d in zip(XY, duv, strict=True):
        p = H @ [x, y, 1.0]
        J = (H[:2, :2] * p[2] - np.outer(p[:2], H[2, :2])) / p[2] ** 2
        out.append(np.linalg.solve(J, d))
    return np.array(out)


def measure(data_dir, pattern=(7, 7), square_mm: float = 25.0) -> dict:
    try:
        files = photo_paths(data_dir)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    views = detect_views(files, pattern)
    if len(views) < 3:
        raise SystemExit(f"{data_dir}: the {pattern[0]}x{pattern[1]} board was found in only {len(views)} images")
    res, uvs = calibrate(views, pattern)
    out = {"images": len(files), "views": len(views), "image_size_px": list(views[0][2].shape[::-1]),
           "calibration_model": "heikkila (k1 k2 p1 p2)", "fx_px": float(res.camera.fx), "fy_px": float(res.camera.fy),
           "cx_px": float(res.camera.K[0, 2]), "cy_px": float(res.camera.K[1, 2])}
    # the radial-only fit (k1 k2): the simulated webcam's true lens (bench.sim.imaging.WEBCAM_DISTORTION)
    rad, _ = calibrate(views, pattern, "radial")
    out.update({"radial_rms_px": float(rad.rms_px), "radial_k1": float(np.ravel(rad.dist)[0]),
                "radial_k2": float(np.ravel(rad.dist)[1]), "radial_cx_px": float(rad.K[0, 2]),
                "radial_cy_px": float(rad.K[1, 2])})
    out.update(residual_statistics(res.residuals_px, pattern, uvs))
    out.update(measure_board_bow(res, uvs, pattern, square_mm))
    out.update(measure_print_error(views, pattern, square_mm))
    out.update(measure_board_shape(views, pattern, square_mm))
    q = [estimate_jpeg_quality(Path(f).read_bytes()) for f in files if f.lower().endswith(".jpg")]
    if q:
        out["jpeg_quality"] = sorted({int(a) for a, _ in q if a is not None})
        out["jpeg_quality_exact_ijg"] = all(e for _, e in q)
    out.update(measure_noise(views, pattern))
    out.update(measure_sift_precision(views, pattern, res.K, res.dist))
    out.update(measure_blur(views, pattern))
    out.update(measure_edge_profile(views, pattern))
    out.update(measure_vignetting(views, pattern))
    out.update(measure_chromatic(views, pattern))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--pattern", default="7x7", help="inner corners per row x per column")
    ap.add_argument("--square-mm", type=float, default=25.0,
                    help="square size assumed for the bow in mm (the real board's is not recorded; 25 mm = an 8 x 8 "
                         "board printed on A4)")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    try:
        pattern = parse_pattern(args.pattern)
    except ValueError as e:
        raise SystemExit(f"--pattern: {e}") from None
    out = measure(args.data, pattern, args.square_mm)
    for k, v in out.items():
        print(f"{k:34s} {v if not isinstance(v, float) else round(v, 4)}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
