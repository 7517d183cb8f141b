"""``bench calibrate-camera DATASET``: corners, calibration and the OpenCV reference on any dataset folder.

The dataset carries the rig images and ``target.yaml`` describing the target the user built (nominal geometry)::

    type: two_plane_rig       # the thesis's rig (section 5.2): two perpendicular boards
    squares: 7
    size_mm: 197              # pattern size of one board
    margin_mm: 20             # white border from the fold to the pattern
  or
    type: planar
    inner: [7, 7]             # inner corners per row, rows
    square_mm: 28.14

Outputs in ``out``: ``camera.yaml`` (OpenCV keys + the thesis's parameters), ``calibration.json`` (RMS, per-view
χ (Eq. 196), parameters with standard errors, OpenCV's result on the same detections), ``per_view.csv``
(Table 3's α, β, θ, u0, v0, χ per view) and ``residuals.png`` (Figures 44/53).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from bench.camera.calibration import calibrate_camera, opencv_reference, per_view_pinhole
from bench.camera.corners import extract_corners_opencv, extract_corners_thesis, planar_board, two_plane_rig
from bench.camera.io import write_camera_yaml
from bench.camera.plots import plot_residual_vectors
from bench.dataset import load_dataset
from bench.errors import ConfigError
from bench.fileio import atomic_write_text, write_table_csv

_TARGET_KEYS = {"type", "squares", "size_mm", "margin_mm", "inner", "square_mm"}


def load_target(path):
    """The calibration target geometry from ``target.yaml`` (see the module docstring), SI inside."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, "<file>", "not found (the dataset must describe its calibration target)")
    try:
        t = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(path, "<file>", f"not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(t, dict):
        raise ConfigError(path, "<top>", "expected a mapping")
    bad = set(t) - _TARGET_KEYS
    if bad:
        raise ConfigError(path, sorted(bad)[0], f"unknown key (allowed: {', '.join(sorted(_TARGET_KEYS))})")

    def num(key, default=None):
        v = t.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
            raise ConfigError(path, key, f"expected a non-negative number, got {v!r}")
        return float(v)

    kind = t.get("type")
    if kind == "two_plane_rig":
        squares = t.get("squares", 7)
        if not isinstance(squares, int) or squares < 3:
            raise ConfigError(path, "squares", f"expected an integer >= 3, got {squares!r}")
        return two_plane_rig(squares, num("size_mm") * 1e-3, num("margin_mm", 0.0) * 1e-3)
    if kind == "planar":
        inner = t.get("inner")
        if not (isinstance(inner, list) and len(inner) == 2 and all(isinstance(v, int) and v >= 2 for v in inner)):
            raise ConfigError(path, "inner", f"expected [corners per row, rows], got {inner!r}")
        return planar_board(tuple(inner), num("square_mm") * 1e-3)
    raise ConfigError(path, "type", f"expected 'two_plane_rig' or 'planar', got {kind!r}")


@dataclass
class DatasetCorners:
    """Corners detected in the views of a dataset (:func:`detect_dataset_corners`).

    Attributes
    ----------
    names : list of str
        Views in which the whole target was found, in manifest order.
    object_points : list of ndarray (N_i, 3)
        Target points (m, target frame) of each used view.
    image_points : list of ndarray (N_i, 2)
        Detected pixels (px), same order.
    image_size : (int, int)
        ``(width, height)`` of the images (px).
    skipped : list of str
        ``"view: reason"`` for the views where the target was not found.
    geometry : BoardGeometry
        The target of ``target.yaml``.
    detect_s : float
        Wall time of the detection (s).
    """

    names: list
    object_points: list
    image_points: list
    image_size: tuple
    skipped: list
    geometry: object
    detect_s: float


def detect_dataset_corners(root, extractor: str = "thesis", camera=None) -> DatasetCorners:
    """Detect the target of ``target.yaml`` in every view of a dataset with the thesis's or OpenCV's extractor.

    ``camera`` (thesis extractor only): a first calibration; the lines are then fitted in ideal pixels
    (:func:`~bench.camera.corners.extract_corners_thesis`). One-line :class:`ConfigError` when the views differ in
    size or the target is found in no view.
    """
    t0 = time.perf_counter()
    ds = load_dataset(root)
    geometry = load_target(ds.root / "target.yaml")
    if extractor not in ("thesis", "opencv"):
        raise ValueError(f"extractor: expected 'thesis' or 'opencv', got {extractor!r}")
    if camera is not None and extractor != "thesis":
        raise ValueError("camera: only the thesis extractor fits lines in ideal pixels")
    size = None
    Xs, uvs, names, skipped = [], [], [], []
    for v in ds.views:
        if v.image_path is None:  # a frame of readings only (e.g. a taught tool pose)
            continue
        img = v.image()
        if size is None:
            size = (img.shape[1], img.shape[0])
        elif (img.shape[1], img.shape[0]) != size:
            raise ConfigError(v.image_path, "<size>", f"{img.shape[1]}x{img.shape[0]}, other views are "
                                                      f"{size[0]}x{size[1]}")
        res = (extract_corners_thesis(img, geometry, camera=camera) if extractor == "thesis" else
               extract_corners_opencv(img, geometry))
        if not res.success:
            skipped.append(f"{v.name}: {res.message}")
            continue
        Xs.append(res.object_points)
        uvs.append(res.uv)
        names.append(v.name)
    if not Xs:
        raise ConfigError(ds.root, "views", "the target was found in no view: " + "; ".join(skipped[:3]))
    return DatasetCorners(names, Xs, uvs, size, skipped, geometry, time.perf_counter() - t0)


def calibrate_dataset(root, out, model: str = "heikkila", extractor: str = "thesis", verbose: bool = True):
    """Detect corners in every view, calibrate, compare with OpenCV; returns ``(CalibrationResult, report)``."""
    ds = load_dataset(root)
    det = detect_dataset_corners(ds.root, extractor)
    Xs, uvs, names, skipped, size = det.object_points, det.image_points, det.names, det.skipped, det.image_size
    t_detect = det.detect_s
    result = calibrate_camera(Xs, uvs, size, model=model)
    ref = opencv_reference([X.astype(np.float32) for X in Xs], [u.astype(np.float32) for u in uvs], size, model)
    report = {"dataset": str(ds.root), "model": model, "extractor": extractor, "views_used": names,
              "views_skipped": skipped, "success": result.success, "message": result.message,
              "reproj_rms_px": result.rms_px, "per_view_rms_px": dict(zip(names, map(float, result.per_view_rms_px),
                                                                           strict=True)),
              "opencv_rms_px": ref.rms_px, "timings_s": {"detect_s": t_detect, **result.timings_s}}
    if result.success:
        report["K"] = result.K.tolist()
        report["dist"] = result.dist.tolist()
        report["standard_errors"] = result.standard_errors
        report["opencv_K"] = ref.K.tolist()
        report["opencv_dist"] = ref.dist.tolist()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if result.success:
        write_camera_yaml(out / "camera.yaml", result.camera)
        rows = per_view_pinhole(Xs, uvs)
        cols = [k for k in rows[0] if k != "note"]
        write_table_csv(out / "per_view.csv", {"view": names, **{k: [r[k] for r in rows] for k in cols}})
        first = ds.view(names[0]).image()
        plot_residual_vectors(out / "residuals.png", uvs[0], result.residuals_px[0], image=first, image_size=size)
    atomic_write_text(out / "calibration.json", json.dumps(report, indent=2, default=float) + "\n")
    if verbose:
        print(f"{len(names)} views used, {len(skipped)} skipped; RMS {result.rms_px:.4f} px (OpenCV on the same "
              f"detections: {ref.rms_px:.4f} px)")
        for s in skipped:
            print(f"  skipped {s}")
        if result.success:
            print("K =", np.array2string(result.K, precision=3), "dist =", np.array2string(result.dist, precision=5))
    return result, report
