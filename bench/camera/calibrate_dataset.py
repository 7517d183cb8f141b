"""``bench calibrate-camera``: corners, calibration and the OpenCV reference on a dataset or a plain folder of photos.

Two sources of views:

* a **dataset folder** (:mod:`bench.dataset`): its views (those with role ``rig`` if any has it) and ``target.yaml``;
* a **plain folder of photos** (``*.png``, ``*.jpg``, ``*.jpeg``, views named by file stem, in name order), the target
  described by the command's flags (``--target chessboard --inner 9x6 --square-mm 25``), which is also what a
  ``target.yaml`` holds.

``target.yaml`` (documented for users in ``docs/tutorial_real_data.md``; every key is checked, one-line errors)::

    type: chessboard          # a flat chessboard ("planar" is read as a synonym)
    inner: [9, 6]             # inner corners per row, rows (both >= 2)
    square_mm: 25             # side of one square (mm, > 0)
  or
    type: two_plane_rig       # the thesis's rig (section 5.2): two perpendicular boards
    squares: 7                # squares per side of one board (>= 3; default 7)
    size_mm: 197              # side of the pattern of one board (mm, > 0)
    margin_mm: 20             # white border from the fold and the bottom to the pattern (mm, >= 0; default 0)

Either type may state the printed target's tolerances (optional ``tolerance`` mapping, 1-sigma values:
:mod:`bench.camera.target_tolerance`); a calibration then also reports what they leave in its results: the
standard errors in ``calibration.json`` are the pixel noise's plus the consider covariance of
:data:`TOLERANCE_DRAWS` calibrations of the same detections against targets drawn from the tolerances
(:func:`~bench.camera.target_tolerance.calibration_with_tolerance`; ``tolerance_draws`` says how many converged).

Outputs in ``out``: ``camera.yaml`` (OpenCV keys + the thesis's parameters), ``calibration.json`` (RMS, per-view
χ (Eq. 196), parameters with standard errors, OpenCV's result on the same detections), ``per_view.csv``
(Table 3's α, β, θ, u0, v0, χ per view) and ``residuals.png`` (Figures 44/53). With a robot file (``--robot``, e.g.
the output of ``bench calibrate-robot``) and joint readings for the views, also the camera mount on link 5 by
``AX = XB`` (:func:`bench.vision.handeye.hand_eye_axxb`; the target's symmetric labellings made consistent from the
motions alone, :func:`~bench.vision.handeye.resolve_target_symmetry_screw`), written into ``out/robot.yaml`` (the
robot file with ``calibration.camera_mount`` added, its errors kept) and ``calibration.json`` (``mount``).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import yaml
from pydantic import BeforeValidator

from bench.camera.calibration import calibrate_camera, opencv_reference, per_view_pinhole
from bench.camera.corners import extract_corners_opencv, extract_corners_thesis, planar_board, two_plane_rig
from bench.camera.io import write_camera_yaml
from bench.camera.plots import plot_residual_vectors
from bench.camera.target_tolerance import calibration_with_tolerance, parse_tolerance
from bench.config import NonNegFloat, PositiveFloat, Section, at_least, parse
from bench.dataset import IMAGE_SUFFIXES, View, load_dataset, photo_files
from bench.errors import ConfigError
from bench.fileio import atomic_write_text, prepare_output_dir, read_yaml, write_table_csv
from bench.geometry.transforms import homogeneous, rot_z


def _inner(v):
    if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool) and x >= 2
                                                        for x in v)):
        raise ValueError(f"expected [inner corners per row, rows], both >= 2, got {v!r}")
    return v


class Chessboard(Section):
    """``target.yaml`` of a flat chessboard (``type: chessboard``; ``planar`` is read as a synonym)."""

    type: str
    inner: Annotated[list[int], BeforeValidator(_inner)]
    square_mm: PositiveFloat
    tolerance: dict | None = None  # bench.camera.target_tolerance.Tolerance


class TwoPlaneRig(Section):
    """``target.yaml`` of the thesis's rig (``type: two_plane_rig``, section 5.2): two perpendicular boards."""

    type: str
    squares: Annotated[int, at_least(3, "expected an integer >= 3 (squares per side), got {v}")] = 7
    size_mm: PositiveFloat
    margin_mm: NonNegFloat = 0.0
    tolerance: dict | None = None


#: target types and their models
TARGETS = {"chessboard": Chessboard, "two_plane_rig": TwoPlaneRig}
_TARGET_SYNONYMS = {"planar": "chessboard"}
#: calibrations against targets drawn from target.yaml's tolerances behind the reported standard errors
TOLERANCE_DRAWS = 48


def parse_target(t, source):
    """The target geometry (SI) from a ``target.yaml`` mapping (:data:`TARGETS`, module docstring); one-line
    ConfigError naming ``source`` and the key for anything else."""
    if not isinstance(t, dict):
        raise ConfigError(source, "<top>", f"expected a mapping (type: chessboard|two_plane_rig, ...), got {t!r}")
    kind = _TARGET_SYNONYMS.get(t.get("type"), t.get("type"))
    if kind not in TARGETS:
        raise ConfigError(source, "type", f"expected 'chessboard' or 'two_plane_rig', got {t.get('type')!r}")
    try:
        v = parse(TARGETS[kind], t, source)
    except ConfigError as exc:
        other = [k for k, m in TARGETS.items() if k != kind and exc.field in m.model_fields]
        if exc.problem.startswith("unknown key") and other:
            raise ConfigError(source, exc.field, f"unknown key for type {kind} (a key of type {other[0]})") from None
        raise
    if v["tolerance"] is not None:
        parse_tolerance(v["tolerance"], source)
    if kind == "two_plane_rig":
        return two_plane_rig(v["squares"], v["size_mm"] * 1e-3, v["margin_mm"] * 1e-3)
    return planar_board(tuple(v["inner"]), v["square_mm"] * 1e-3)


def load_target_tolerance(path):
    """The target's stated tolerances from ``target.yaml`` (:class:`~bench.camera.target_tolerance.TargetTolerance`),
    or None when the file states none; the file is checked as by :func:`load_target`."""
    load_target(path)
    t = yaml.safe_load(Path(path).read_text())
    return parse_tolerance(t["tolerance"], Path(path)) if "tolerance" in t else None


def load_target(path):
    """The calibration target geometry from ``target.yaml`` (see the module docstring), SI inside."""
    path = Path(path)
    return parse_target(read_yaml(path, "not found (the dataset must describe its calibration target)"), path)


def target_spec(target: str, inner: str | None = None, square_mm: float | None = None, squares: int | None = None,
                size_mm: float | None = None, margin_mm: float | None = None) -> dict:
    """The ``target.yaml`` mapping from command-line flags (``--target chessboard --inner 9x6 --square-mm 25``, or
    ``--target two_plane_rig --size-mm 197 [--squares 7] [--margin-mm 20]``), checked by :func:`parse_target`."""
    kind = _TARGET_SYNONYMS.get(str(target).replace("-", "_"), str(target).replace("-", "_"))
    if kind not in TARGETS:
        raise ConfigError("--target", kind, "expected chessboard or two_plane_rig")
    flags = {"inner": inner, "square_mm": square_mm, "squares": squares, "size_mm": size_mm, "margin_mm": margin_mm}
    fields = {k: f for k, f in TARGETS[kind].model_fields.items() if k not in ("type", "tolerance")}
    required = {k for k, f in fields.items() if f.is_required()}

    def flag(key):
        return "--" + key.replace("_", "-")

    allowed = ", ".join(flag(k) for k in sorted(fields))
    for key, value in flags.items():
        if value is not None and key not in fields:
            raise ConfigError(f"--target {kind}", flag(key), f"not a flag of this target (its flags: {allowed})")
        if value is None and key in required:
            raise ConfigError(f"--target {kind}", flag(key), f"missing (this target needs "
                                                                  f"{', '.join(flag(k) for k in sorted(required))})")
    spec = {"type": kind}
    for key, value in flags.items():
        if value is None:
            continue
        if key == "inner":
            parts = str(value).lower().replace("*", "x").split("x")
            try:
                value = [int(v) for v in parts]
            except ValueError:
                value = None
            if value is None or len(value) != 2 or min(value) < 2:
                raise ConfigError(f"--target {kind}", "--inner", f"expected WxH inner corners, both >= 2 (e.g. "
                                                                 f"9x6), got {inner!r}")
        spec[key] = value
    try:
        parse_target(spec, "--target")
    except ConfigError as exc:  # name the flag, not the yaml key
        raise ConfigError(f"--target {kind}", flag(exc.field), exc.problem) from None
    return spec


def target_yaml_text(spec: dict) -> str:
    """``target.yaml`` text of a :func:`target_spec` mapping (units in the key names)."""
    lines = ["# calibration target (docs/tutorial_real_data.md: target.yaml)"]
    for key, value in spec.items():
        text = f"[{', '.join(str(v) for v in value)}]" if isinstance(value, list) else yaml.safe_dump(value).split(
            "\n")[0]
        lines.append(f"{key}: {text}")
    return "\n".join(lines) + "\n"


def target_symmetries(geometry) -> list:
    """Rigid motions ``S`` (4x4, target frame) after which the target looks the same, so that a detector may label a
    view as ``T_cam_target S``: the two-plane rig's half turn about the horizontal bisector of its boards; a
    chessboard's half turn about its normal through its centre (and the quarter turns of a square grid)."""
    X = geometry.object_points()
    if geometry.name == "planar":
        c = X.mean(axis=0)
        nx, ny = geometry.planes[0].inner
        turns = (1, 2, 3) if nx == ny else (2,)
        return [homogeneous(R, c - R @ c) for R in (rot_z(k * np.pi / 2) for k in turns)]
    z_mid = float(np.mean(X[:, 2]))
    return [homogeneous(np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]), [0.0, 0.0, 2 * z_mid])]


def photo_views(folder) -> list:
    """The views of a plain folder of photos: one :class:`~bench.dataset.View` per image file (module docstring)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(folder, "<folder>", "not found")
    files = photo_files(folder)
    if not files:
        other = sorted(p.name for p in folder.iterdir())[:3]
        raise ConfigError(folder, "<folder>", f"no photos ({', '.join(IMAGE_SUFFIXES)}) and no manifest.yaml"
                                              + (f"; holds {', '.join(other)}" if other else ": empty"))
    stems = {}
    for f in files:
        if f.stem in stems:
            raise ConfigError(f, "<file>", f"two photos named {f.stem!r} ({stems[f.stem].name}, {f.name})")
        stems[f.stem] = f
    return [View(f.stem, f) for f in files]


def _views_and_target(root, target: dict | None):
    """``(views, geometry, dataset or None)`` of a dataset folder or a plain folder of photos."""
    root = Path(root)
    if (root / "manifest.yaml").is_file():
        ds = load_dataset(root)
        if target is not None:
            if (ds.root / "target.yaml").is_file():
                raise ConfigError(ds.root / "target.yaml", "<file>", "the dataset describes its target: drop --target "
                                                                     "(or edit target.yaml)")
            geometry = parse_target(target, "--target")
        else:
            geometry = load_target(ds.root / "target.yaml")
        views = [v for v in ds.views if v.image_path is not None]
        rig = [v for v in views if v.role == "rig"]
        return (rig or views), geometry, ds
    if target is None:
        if root.is_dir():
            raise ConfigError(root, "<folder>", "neither a dataset (no manifest.yaml) nor described: for a plain "
                                                "folder of photos give --target chessboard --inner WxH --square-mm S")
        raise ConfigError(root, "<folder>", "not found")
    return photo_views(root), parse_target(target, "--target"), None


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


def detect_dataset_corners(root, extractor: str = "thesis", camera=None, target: dict | None = None, *,
                           subpixel: bool = True) -> DatasetCorners:
    """Detect the target in every view of a dataset (or plain folder of photos) with the thesis's or OpenCV's
    extractor.

    ``target``: a :func:`target_spec` mapping, required for a plain folder of photos (a dataset has ``target.yaml``).
    ``camera`` (thesis extractor only): a first calibration; the lines are then fitted in ideal pixels
    (:func:`~bench.camera.corners.extract_corners_thesis`). ``subpixel=False`` (thesis extractor only): the lines are
    fitted to the binary edge map's pixels, as printed (§3.3.5), not to sub-pixel edge positions. One-line
    :class:`ConfigError` when the views differ in size or the target is found in no view.
    """
    t0 = time.perf_counter()
    if extractor not in ("thesis", "opencv"):
        raise ValueError(f"extractor: expected 'thesis' or 'opencv', got {extractor!r}")
    if camera is not None and extractor != "thesis":
        raise ValueError("camera: only the thesis extractor fits lines in ideal pixels")
    if not subpixel and extractor != "thesis":
        raise ValueError("subpixel: only the thesis extractor has edge positions to round")
    views, geometry, _ = _views_and_target(root, target)
    size = None
    Xs, uvs, names, skipped = [], [], [], []
    for v in views:
        img = v.image()
        if size is None:
            size = (img.shape[1], img.shape[0])
        elif (img.shape[1], img.shape[0]) != size:
            raise ConfigError(v.image_path, "<size>", f"{img.shape[1]}x{img.shape[0]}, other views are "
                                                      f"{size[0]}x{size[1]}")
        res = (extract_corners_thesis(img, geometry, camera=camera, subpixel=subpixel) if extractor == "thesis" else
               extract_corners_opencv(img, geometry))
        if not res.success:
            skipped.append(f"{v.name}: {res.message}")
            continue
        Xs.append(res.object_points)
        uvs.append(res.uv)
        names.append(v.name)
    if not Xs:
        raise ConfigError(root, "views", f"the target was found in none of the {len(views)} views: "
                                         + "; ".join(skipped[:3]))
    return DatasetCorners(names, Xs, uvs, size, skipped, geometry, time.perf_counter() - t0)


def calibrate_mount(robot_file, views, T_cam_target, geometry) -> dict:
    """The camera mount on link 5 by ``AX = XB`` from the used views' joint readings (module docstring).

    ``views``: the :class:`~bench.dataset.View` objects of the calibrated views (with ``q``); ``T_cam_target
    (N, 4, 4)`` their extrinsics. Returns ``{"robot", "eps", "result" (HandEyeResult), "symmetry" (index per view),
    "angle_mismatch_deg"}``; one-line ConfigError when readings are missing or the problem is degenerate.
    """
    from bench.robot.calibration_file import load_calibrated_robot
    from bench.robot.orientation import link5_frame
    from bench.vision.handeye import hand_eye_axxb, resolve_target_symmetry_screw

    robot, eps, _ = load_calibrated_robot(robot_file)
    missing = [v.name for v in views if v.q is None]
    if missing:
        raise ConfigError("joints.csv", missing[0], f"no joint readings for this view: the mount (--robot) needs "
                                                    f"them for every calibrated view ({len(missing)} missing)")
    T_base_l5 = np.stack([link5_frame(robot, robot.check_q(v.q, f"joints.csv ({v.name})"), eps) for v in views])
    B, choice, worst = resolve_target_symmetry_screw(T_base_l5, T_cam_target, target_symmetries(geometry))
    he = hand_eye_axxb(T_base_l5, B)
    if not he.success:
        raise ConfigError("rig views", "mount", f"AX = XB failed: {he.message}")
    return {"robot": robot, "eps": eps, "result": he, "symmetry": choice.tolist(),
            "angle_mismatch_deg": float(np.rad2deg(worst))}


def calibrate_dataset(root, out, model: str = "heikkila", extractor: str = "thesis", verbose: bool = True,
                      target: dict | None = None, k3: bool = False, robot=None):
    """Detect corners in every view, calibrate, compare with OpenCV; returns ``(CalibrationResult, report)``.

    Parameters
    ----------
    root : path
        A dataset folder or a plain folder of photos (module docstring).
    out : path
        Output folder (new, empty, or an earlier output of this command).
    model : {"heikkila", "radial", "pinhole"}
    extractor : {"thesis", "opencv"}
    target : dict, optional
        :func:`target_spec` of the target (a plain folder of photos needs it; a dataset has ``target.yaml``).
    k3 : bool
        Also fit the third radial coefficient ``k3`` (OpenCV order ``k1, k2, p1, p2, k3``).
    robot : path, optional
        A (calibrated) robot file: the camera mount is calibrated too (dataset views with joint readings) and
        ``out/robot.yaml`` written.
    """
    if robot is not None and not (Path(root) / "manifest.yaml").is_file():
        raise ConfigError(root, "--robot", "the mount needs the joint readings of a dataset (bench dataset init), "
                                           "not a plain folder of photos")
    out = prepare_output_dir(out, "calibrate-camera")
    views, _, ds = _views_and_target(root, target)
    det = detect_dataset_corners(root, extractor, target=target)
    Xs, uvs, names, skipped, size = det.object_points, det.image_points, det.names, det.skipped, det.image_size
    t_detect = det.detect_s
    result = calibrate_camera(Xs, uvs, size, model=model, k3=k3)
    tol_draws, tol_warning = 0, ""
    if target is not None:  # the target from flags or a mapping: its tolerance, if it states one
        tol_file = "--target"
        tolerance = parse_tolerance(target["tolerance"], tol_file) if "tolerance" in target else None
    else:
        tol_file = ds.root / "target.yaml" if ds is not None else None
        tolerance = load_target_tolerance(tol_file) if tol_file is not None else None
    if result.success and tolerance is not None and tolerance.any:  # the rig's stated tolerances in the covariance
        if verbose:
            print(f"the target's stated tolerances ({tol_file}): {TOLERANCE_DRAWS} calibrations against drawn "
                  "targets ...")
        try:
            result, _, tol_draws = calibration_with_tolerance(result, det.geometry, tolerance, Xs, uvs,
                                                              TOLERANCE_DRAWS, tol_file)
        except ConfigError as exc:  # too few draws converged: the calibration stands, its errors say so
            tol_warning = f"standard errors without the target's tolerances: {exc}"
            if verbose:
                print(f"warning: {tol_warning}")
    ref = opencv_reference([X.astype(np.float32) for X in Xs], [u.astype(np.float32) for u in uvs], size, model,
                           k3=k3)
    source = str(ds.root) if ds is not None else str(Path(root))
    report = {"dataset" if ds is not None else "photos": source, "target": target or "target.yaml",
              "model": model, "k3": bool(k3), "extractor": extractor, "views_used": names,
              "views_skipped": skipped, "success": result.success, "message": result.message,
              "reproj_rms_px": result.rms_px, "per_view_rms_px": dict(zip(names, map(float, result.per_view_rms_px),
                                                                           strict=True)),
              "opencv_rms_px": ref.rms_px, "tolerance_draws": tol_draws, "tolerance_warning": tol_warning,
              "timings_s": {"detect_s": t_detect, **result.timings_s}}
    by_name = {v.name: v for v in views}
    if result.success:
        report.update(K=result.K.tolist(), dist=result.dist.tolist(), standard_errors=result.standard_errors,
                      opencv_K=ref.K.tolist(), opencv_dist=ref.dist.tolist())
        write_camera_yaml(out / "camera.yaml", result.camera)
        rows = per_view_pinhole(Xs, uvs)
        cols = [k for k in rows[0] if k != "note"]
        write_table_csv(out / "per_view.csv", {"view": names, **{k: [r[k] for r in rows] for k in cols}})
        first = by_name[names[0]].image()
        plot_residual_vectors(out / "residuals.png", uvs[0], result.residuals_px[0], image=first, image_size=size)
        if robot is not None:
            from bench.robot.calibration_file import write_calibrated_robot

            m = calibrate_mount(robot, [by_name[n] for n in names], result.T_cam_target, det.geometry)
            he = m["result"]
            write_calibrated_robot(out / "robot.yaml", robot, m["robot"], m["eps"], he.T_mount_cam,
                                   notes=f"errors from {Path(robot).name}; camera mount from {len(names)} views of "
                                         f"{Path(source).name} (AX = XB): {he.message}")
            report["mount"] = {"robot": str(robot), "T_link5_cam": he.T_mount_cam.tolist(),
                               "translation_mm": (he.T_mount_cam[:3, 3] * 1e3).tolist(),
                               "rms_rot_deg": float(np.rad2deg(he.rms_rot_rad)),
                               "rms_trans_mm": float(he.rms_trans_m * 1e3), "condition": he.condition,
                               "symmetry_per_view": m["symmetry"],
                               "motion_angle_mismatch_deg": m["angle_mismatch_deg"], "message": he.message}
    atomic_write_text(out / "calibration.json", json.dumps(report, indent=2, default=float) + "\n")
    if verbose:
        print(f"{len(names)} views used, {len(skipped)} skipped; RMS {result.rms_px:.4f} px (OpenCV on the same "
              f"detections: {ref.rms_px:.4f} px)")
        for s in skipped:
            print(f"  skipped {s}")
        if result.success:
            print("K =", np.array2string(result.K, precision=3), "dist =", np.array2string(result.dist, precision=5))
            print(f"wrote {out / 'camera.yaml'}")
        if "mount" in report:
            mt = report["mount"]
            print(f"camera mount (link 5): translation [{', '.join(f'{v:.2f}' for v in mt['translation_mm'])}] mm; "
                  f"AX = XB residual {mt['rms_trans_mm']:.3f} mm, {mt['rms_rot_deg']:.4f} deg; "
                  f"wrote {out / 'robot.yaml'}")
    return result, report
