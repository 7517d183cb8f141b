"""Calibrate the real webcam images (7x7 inner corners, unit squares) with ours and with OpenCV, side by side.

    .venv/bin/python tools/webcam_calibration.py [--data DIR] [--out DIR] [--model heikkila|radial|pinhole]

Detections: ``cv2.findChessboardCornersSB`` (ACCURACY flag). The board is square and symmetric: the corner labelling
of a view can differ from another's by a symmetry of the grid; each view's pose absorbs it (tested), so no reordering
is needed for the intrinsics.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from bench.camera import calibration as cal
from bench.camera.heikkila import fit_implicit_inverse
from bench.camera.photo_stats import board_points, detect_board, photo_paths
from bench.camera.plots import plot_residual_vectors

WEBCAM = Path(__file__).resolve().parents[1] / "tests" / "data" / "real_webcam_chessboard"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(WEBCAM),
                    help="folder of photos (default: the real webcam photos in tests/data)")
    ap.add_argument("--out", default="runs/webcam_calibration")
    ap.add_argument("--model", default="heikkila", choices=cal.MODELS)
    args = ap.parse_args(argv)
    try:
        files = photo_paths(args.data)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    obj = board_points((7, 7))
    Xs, uvs, used = [], [], []
    t0 = time.perf_counter()
    for f in files:
        image = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        if image is None:
            print(f"{f}: unreadable, skipped")
            continue
        corners = detect_board(image, (7, 7))  # findChessboardCornersSB, ACCURACY, OpenCV's RNG seeded
        if corners is None:
            print(f"{f}: board not found, skipped")
            continue
        Xs.append(obj.copy())
        uvs.append(corners)
        used.append(f)
    t_detect = time.perf_counter() - t0
    size = cv2.imread(used[0]).shape[1::-1]
    t0 = time.perf_counter()
    ours = cal.calibrate_camera(Xs, uvs, size, args.model)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = cal.opencv_reference(Xs, uvs, size, args.model)
    t_cv = time.perf_counter() - t0
    print(f"{len(used)} views, {sum(len(u) for u in uvs)} corners; detection {t_detect:.2f} s")
    print(f"{'':12s}{'ours':>16s}{'std':>12s}{'OpenCV':>16s}")
    print(f"{'rms_px':12s}{ours.rms_px:16.10f}{'':12s}{ref.rms_px:16.10f}")
    values_cv = {"fx": ref.K[0, 0], "fy": ref.K[1, 1], "cx": ref.K[0, 2], "cy": ref.K[1, 2],
                 **dict(zip(["k1", "k2", "p1", "p2", "k3"], ref.dist, strict=True))}
    for name, value, std in zip(ours.parameter_names, ours.parameters, ours.std, strict=True):
        print(f"{name:12s}{value:16.8f}{std:12.6f}{values_cv[name]:16.8f}")
    print(f"{'time_s':12s}{t_ours:16.3f}{'':12s}{t_cv:16.3f}")
    print("per-view chi (Eq. 196), px:", np.array2string(ours.per_view_rms_px, precision=3))
    print("thesis parameters:", {k: round(v, 4) for k, v in ours.thesis_parameters().items()})
    inv = fit_implicit_inverse(ours.camera)
    print(f"implicit inverse model (Eq. 77-86): grid rms {inv.rms_px:.4f} px, max {inv.max_px:.4f} px")
    out = Path(args.out)
    png = plot_residual_vectors(out / "residuals_view0.png", uvs[0], ours.residuals_px[0], image=cv2.imread(used[0]),
                                rms_px=ours.per_view_rms_px[0], title=Path(used[0]).name)
    plot_residual_vectors(out / "residuals_all.png", uvs, ours.residuals_px, image_size=size, rms_px=ours.rms_px,
                          title="all views")
    print(f"plots: {png.parent}")


if __name__ == "__main__":
    main()
