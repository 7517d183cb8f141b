"""Scenario kind ``flatport_study``: where the polynomial (Heikkilä) camera model stops describing a flat port.

A camera behind a flat port in water is not a single-viewpoint camera (:mod:`bench.camera.flatport`): the water rays do
not meet in one point. A central model calibrated in water - the thesis's Heikkilä model (Eq. 74-76, section 5.5,
Table 15) - describes it well near the distance it was calibrated at and drifts away from it. This study measures
how far, for several lens-to-glass distances ``d0``, with no image in between (pure numerics, exact optics):

1. **Calibration, noise-free, as a user would do it.** The two-plane rig of section 5.2 (two perpendicular 7 x 7
   boards, :func:`bench.sim.scenes.rig.calibration_rig`) is placed ``calibration.distance_m`` in front of the lens
   (its corner centroid; ``calibration.depth_range_m`` either way, uniform), turned about its fold and tilted (up to
   ``calibration.yaw_deg`` / ``pitch_deg``), with its centroid on a ``calibration.grid`` of image positions spanning
   ``calibration.spread`` of the half-image in each direction, so that the corners cover the whole image (views at
   the border see part of the rig: only the corners ``calibration.margin_px`` inside the image are kept, as a
   detector would). Their pixels are the exact projections through lens + port
   (:func:`bench.scenario.bounds.true_projector`). The pipeline's :func:`bench.camera.calibration.calibrate_camera`
   fits the Heikkilä model (k1, k2, p1, p2; ``calibration.k3`` adds k3) to them; its residual RMS
   (``calib_rms_px_*``) is the model's floor over the calibration volume.

   Start of the Levenberg-Marquardt fit: the paraxial description of the true optics - the lens's distortion, its
   focal lengths times ``n_water / n_air``, the true rig poses seen from the port's paraxial virtual centre
   (:func:`bench.camera.flatport.axis_crossing` of a near-axial ray). The pipeline's own start (DLT/Zhang and the
   radial alternation) stalls on these whole-image views through a port (LM stops at 4-29 px RMS, "points behind the
   camera"); :func:`~bench.camera.calibration.calibrate_camera` then restarts from its pinhole fit and reaches the
   same minimum as the paraxial start (tested). The start does not bias the result: the fit is the least-squares
   minimum.

2. **The fitted camera's frame.** The fitted central camera does not sit at the lens: its centre is where the water
   rays seem to come from (behind the lens, by about the paraxial virtual centre's distance, further for wide
   angles), and with a tilted port it is turned a little (the principal ray bends at the port). ``T_fit_lens`` is
   estimated from the calibration itself, as a user would estimate a camera's mount from its calibration views: the
   rig corners at their true lens-frame positions, all views together, are one object whose pose the fitted camera
   finds by perspective-n-point (:func:`fitted_frame`). No information of the working distance enters it.

3. **Evaluation at working distances** (``evaluation.distance_min_m`` .. ``distance_max_m``, geometric, plus the
   calibration distance). For a grid of ``evaluation.grid`` pixels over the whole image, the true ray (lens
   back-projection, then :func:`bench.camera.flatport.trace_rays` into the water) is followed to the point at
   depth ``z`` (lens frame) = the working distance, and that point is projected by the fitted model: the distance
   to the pixel is the reprojection error (``rms_px``, ``max_px`` over the image). The object-space error (``rms_mm``,
   ``max_mm``) is the distance from the true point to the fitted camera's ray through the same pixel (the lateral
   error of a point the fitted camera would place at that range).

4. **Where a refractive model is needed**: the working distances where the image-RMS error exceeds
   ``threshold.px`` (``threshold.statistic: rms | max``). Default 0.1 px: the SIFT keypoints' localisation noise the
   bench measures in its underwater scenes (``keypoint_sigma_px`` 0.07-0.09 px, section "Bounds and the error
   budget"); a systematic model error above the features' own noise is what a refractive model would remove. The
   window where the polynomial model is good enough is ``[polynomial_ok_from_m, polynomial_ok_to_m]`` (log-log
   interpolated crossings, clipped to the evaluated range); outside it, a refractive model is needed
   (``refractive_needed_below_m`` = its lower edge, ``refractive_needed_above_m`` = its upper edge, both null and
   ``refractive_needed_everywhere = 1`` when the error exceeds the threshold at every evaluated distance).

Port cases: ``port.alignments`` lists ``aligned`` (port normal along the optical axis, no decentre) and/or ``tilted``
(the preset's housing: ~1 deg tilt, 1 mm decentre; ``port.tilt_deg`` replaces the tilt). Glass thickness and indices
come from the optics preset (``port.glass_thickness_mm``, ``port.n_glass``, ``port.n_water`` override them; setting
``n_glass`` and ``n_water`` to the preset's ``n_air`` removes the port optically: the exactness check).

``result.json`` (names are a contract), with the suffix ``<s> = d0_<mm>mm_<alignment>`` (``d0_20mm_aligned``):
``calib_rms_px_<s>``, ``rms_px_at_calib_<s>``, ``rms_px_at_<near>m_<s>``, ``max_px_at_<near>m_<s>``,
``rms_px_at_<far>m_<s>``, ``max_px_at_<far>m_<s>``, ``rms_mm_at_<far>m_<s>`` (distances with ``.`` as ``p``:
``0p2m``, ``3m``), ``polynomial_ok_from_m_<s>``, ``polynomial_ok_to_m_<s>``, ``refractive_needed_below_m_<s>``,
``refractive_needed_above_m_<s>``, ``refractive_needed_everywhere_<s>``, ``centre_offset_axial_mm_<s>`` (fitted centre
along the lens axis, negative = behind the lens), ``centre_offset_lateral_mm_<s>``, ``centre_rotation_deg_<s>``,
``paraxial_centre_axial_mm_<s>``, ``calib_coverage_<s>`` (fraction of the image area inside the calibration corners'
convex hull), ``frame_reproj_rms_px_<s>`` (the calibration corners through the one fitted frame),
``threshold_px``; tables ``flatport_error_vs_distance`` (``alignment, lens_to_glass_mm,
distance_m, rms_px, max_px, rms_mm, max_mm, exceeds_threshold``) and ``flatport_calibration`` (one row per case);
CSVs of both and ``flatport_error_vs_distance.png``.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import Annotated, Literal

import cv2
import numpy as np
from pydantic import Field, model_validator

from bench.camera.calibration import calibrate_camera
from bench.camera.flatport import FlatPort, trace_rays
from bench.camera.model import CameraModel
from bench.camera.refractive import paraxial_centre
from bench.config import (
    Distinct,
    KeyProblem,
    NonNegFloat,
    Number,
    PlotOutputs,
    PositiveFloat,
    ScenarioBase,
    Section,
    section,
)
from bench.errors import ConfigError
from bench.fileio import atomic_save_figure, headless_pyplot
from bench.geometry.transforms import homogeneous, invert, rot_x, rot_y, rotation_angle, transform_points
from bench.scenario.bounds import true_projector
from bench.scenario.results import write_result, write_table_csv
from bench.vision.absolute_orientation import absolute_orientation

ALIGNMENTS = ("aligned", "tilted")
STATISTICS = ("rms", "max")
INDEX = Annotated[float, Field(ge=1, le=3)]  # a refractive index


class Optics(Section):
    preset: str = "underwater_in_water"


class Port(Section):
    lens_to_glass_mm: Annotated[list[Annotated[Number, Field(gt=0, le=500)]], Field(min_length=1), Distinct] = [
        5.0, 10.0, 20.0, 50.0, 100.0]
    alignments: Annotated[list[Literal[ALIGNMENTS]], Field(min_length=1), Distinct] = ["aligned", "tilted"]
    tilt_deg: Annotated[list[Annotated[Number, Field(ge=-20, le=20)]], Field(min_length=2, max_length=2)] | None = None
    glass_thickness_mm: Annotated[float, Field(ge=0, le=200)] | None = None
    n_glass: INDEX | None = None
    n_water: INDEX | None = None


class Calibration(Section):
    distance_m: Annotated[float, Field(ge=0.2, le=10)] = 0.7
    depth_range_m: NonNegFloat = 0.1
    grid: Annotated[list[Annotated[int, Field(ge=1, le=20)]], Field(min_length=2, max_length=2)] = [5, 4]
    spread: Annotated[float, Field(ge=0, le=1)] = 0.9
    yaw_deg: Annotated[float, Field(ge=0, le=45)] = 15.0
    pitch_deg: Annotated[float, Field(ge=0, le=45)] = 10.0
    margin_px: Annotated[float, Field(ge=0, le=100)] = 4.0
    min_points: Annotated[int, Field(ge=6)] = 12
    k3: bool = False

    @model_validator(mode="after")
    def _depth_and_views(self):
        if self.depth_range_m > 0.5 * self.distance_m:
            raise KeyProblem("depth_range_m", f"expected 0..{0.5 * self.distance_m:g} m (half the distance), got "
                                              f"{self.depth_range_m}")
        if self.grid[0] * self.grid[1] < 2:
            raise KeyProblem("grid", f"expected [n_u, n_v] with >= 2 views, got {self.grid}")
        return self


class Evaluation(Section):
    distance_min_m: PositiveFloat = 0.2
    distance_max_m: Annotated[float, Field(gt=0, le=100)] = 3.0
    distances: Annotated[int, Field(ge=2, le=200)] = 15
    grid: Annotated[list[Annotated[int, Field(ge=2, le=1000)]], Field(min_length=2, max_length=2)] = [64, 48]

    @model_validator(mode="after")
    def _ordered(self):
        if not self.distance_min_m < self.distance_max_m:
            raise KeyProblem("distance_max_m", f"expected distance_min_m < distance_max_m, got "
                                               f"{self.distance_min_m}, {self.distance_max_m}")
        return self


class Threshold(Section):
    px: PositiveFloat = 0.1
    statistic: Literal[STATISTICS] = "rms"


class Refractive(Section):
    """The refractive model (bench.camera.refractive) calibrated from the same views with noise_px of pixel noise,
    lens free, started from the central fit and a lens-to-glass distance start_offset_mm off (a datasheet's)."""

    enabled: bool = True
    noise_px: Annotated[float, Field(ge=0, le=5)] = 0.1
    start_offset_mm: Annotated[float, Field(ge=-10, le=10)] = 3.0


class Scenario(ScenarioBase):
    """A ``flatport_study`` scenario file."""

    optics: Optics = section(Optics)
    port: Port = section(Port)
    calibration: Calibration = section(Calibration)
    evaluation: Evaluation = section(Evaluation)
    threshold: Threshold = section(Threshold)
    refractive: Refractive = section(Refractive)
    outputs: PlotOutputs = section(PlotOutputs)


TABLE = "flatport_error_vs_distance"
CALIB_TABLE = "flatport_calibration"


# ------------------------------------------------------------------------------------------------ configuration


def _optics(cfg):
    """``(lens CameraModel, preset FlatPort)`` of ``optics.preset``."""
    from bench.camera.presets import load_preset
    from bench.sim.optics_presets import optics_preset, optics_preset_names

    src, name = cfg["_file"], cfg["optics"]["preset"]
    if name not in optics_preset_names():
        raise ConfigError(src, "optics.preset", f"unknown {name!r} (known: {', '.join(optics_preset_names())})")
    preset = optics_preset(name)
    if preset.port is None:
        raise ConfigError(src, "optics.preset", f"{name!r} has no port (choose one with a housing)")
    return load_preset(preset.lens_camera), preset.port


def _check(cfg, port0: FlatPort):
    """The checks that need the optics preset's port; returns the cases ``[(alignment, d0_mm, FlatPort)]``."""
    src, p = cfg["_file"], cfg["port"]
    D, dr = cfg["calibration"]["distance_m"], cfg["calibration"]["depth_range_m"]
    lo = cfg["evaluation"]["distance_min_m"]
    tilt = port0.tilt if p["tilt_deg"] is None else np.deg2rad(np.asarray(p["tilt_deg"], float))
    repl = {k: p[k] for k in ("n_glass", "n_water") if p[k] is not None}
    if p["glass_thickness_mm"] is not None:
        repl["t"] = p["glass_thickness_mm"] * 1e-3
    cases = []
    for a in p["alignments"]:
        for d0 in [float(d) for d in p["lens_to_glass_mm"]]:
            kw = dict(repl, d0=d0 * 1e-3, source=f"{src}: port")
            if a == "aligned":
                kw.update(tilt=np.zeros(2), decentre=np.zeros(2))
            else:
                kw["tilt"] = tilt
            try:
                port = dataclasses.replace(port0, **kw)
            except ConfigError as exc:
                raise ConfigError(src, "port.lens_to_glass_mm", f"{d0:g} mm ({a}): {exc.problem}") from None
            outer = (port.h + port.t) / np.cos(np.linalg.norm(port.tilt))
            if lo <= outer + 0.01 or D - dr <= outer + 0.05:
                raise ConfigError(src, "evaluation.distance_min_m" if lo <= outer + 0.01 else "calibration.distance_m",
                                  f"must stay beyond the outer glass surface ({outer * 1e3:.0f} mm for d0 = {d0:g} mm"
                                  f", + 10 mm for points, + 50 mm for the rig)")
            cases.append((a, d0, port))
    return cases


def validate(cfg: dict) -> None:
    """Check every value of a loaded scenario without running it (``bench sweep`` does, per grid point)."""
    _check(cfg, _optics(cfg)[1])


# ------------------------------------------------------------------------------------------------ the study


def _axis(n):
    return np.zeros(1) if n == 1 else np.linspace(-1.0, 1.0, n)


def rig_views(lens: CameraModel, port: FlatPort, rig, calib: dict, rng: np.random.Generator, source="calibration"):
    """Rig poses and their exact corner pixels for a noise-free calibration through lens + port.

    Parameters
    ----------
    lens : CameraModel
        The lens inside the housing.
    port : FlatPort
    rig : SceneObject
        :func:`bench.sim.scenes.rig.calibration_rig` (``features["corners"]`` (M, 3), rig frame, m).
    calib : dict
        The scenario's ``calibration`` section (see the module docstring).
    rng : numpy.random.Generator
        Depth, yaw and pitch of each view.

    Returns
    -------
    T_lens_rig : ndarray (V, 4, 4)
        Rig poses in the lens frame (m).
    X : list of ndarray (N_k, 3)
        The corners each view keeps (rig frame, m): those ``margin_px`` inside the image.
    uv : list of ndarray (N_k, 2)
        Their exact pixels (px).
    """
    from bench.sim.scenes.xy_table import reference_pose

    corners = rig.features["corners"]
    T_ref = reference_pose(rig, 1.0)  # fold vertical, bisector towards the camera (section 5.2's placement)
    T_ref = homogeneous(np.eye(3), -transform_points(T_ref, corners).mean(axis=0)) @ T_ref  # centroid at the origin
    project = true_projector(lens, port)
    W, H = lens.size
    nu, nv = calib["grid"]
    T_out, X_out, uv_out = [], [], []
    placements = [(a_u, a_v) for a_v in _axis(nv) for a_u in _axis(nu)]  # row by row, top left first
    for k, (a_u, a_v) in enumerate(placements):
        uv_target = np.array([(W - 1) / 2 + a_u * calib["spread"] * W / 2, (H - 1) / 2 + a_v * calib["spread"] * H / 2])
        o, w, ok = trace_rays(lens.unproject(uv_target), port)
        z = calib["distance_m"] + rng.uniform(-1, 1) * calib["depth_range_m"]
        p_centroid = o + (z - o[2]) / w[2] * w  # on the true ray of the target pixel, at depth z
        R = rot_y(np.deg2rad(rng.uniform(-1, 1) * calib["yaw_deg"])) @ rot_x(
            np.deg2rad(rng.uniform(-1, 1) * calib["pitch_deg"]))
        T = homogeneous(R, p_centroid) @ T_ref
        uv = project(transform_points(T, corners))
        keep = np.all(np.isfinite(uv), axis=1) & lens.in_image(uv, border=calib["margin_px"])
        if np.count_nonzero(keep) < calib["min_points"]:
            raise ConfigError(source, f"view {k + 1}", f"only {np.count_nonzero(keep)} rig corners in the image "
                              f"(< calibration.min_points = {calib['min_points']}): lower calibration.spread")
        T_out.append(T)
        X_out.append(corners[keep])
        uv_out.append(uv[keep])
    return np.array(T_out), X_out, uv_out


def fit_central_model(lens: CameraModel, port: FlatPort, T_lens_rig, X, uv, k3: bool):
    """Heikkilä fit (:func:`calibrate_camera`) of the exact views, started from the paraxial optics (module doc)."""
    c = paraxial_centre(port)
    K0 = lens.K.copy()
    K0[:2, :2] *= port.n_water / port.n_air  # focal lengths (and skew) times the paraxial magnification
    T_par_lens = homogeneous(np.eye(3), -c)
    start = (K0, lens.dist, np.array([T_par_lens @ T for T in T_lens_rig]))
    return calibrate_camera(X, uv, lens.size, model="heikkila", k3=k3, initial=start)


def fitted_frame(res, T_lens_rig, X, uv):
    """``T_fit_lens`` (4, 4): the lens frame in the fitted camera's, from the calibration views alone.

    The rig corners at their true positions in the lens frame, all views together, are one object seen by the fitted
    camera: its pose (perspective-n-point, OpenCV's Levenberg-Marquardt ``solvePnPRefineLM`` on the reprojection
    error, with the fitted intrinsics and distortion) is ``T_fit_lens``. It starts from the absolute orientation
    (Arun/Umeyama SVD) of the corners at the true vs the fitted poses. The reprojection fit is the one that matters
    for image errors: the absolute orientation weighs millimetres at ~0.7 m, where a turn of the camera and a shift of
    its centre are nearly the same, and with a tilted port it trades ~0.16 deg of turn for a ~1.7 mm sideways shift
    (twice the reprojection RMS, and a parallax error that grows away from the calibration distance; measured).

    Returns
    -------
    T_fit_lens : ndarray (4, 4)
    reproj_rms_px : float
        RMS (px) of the calibration corners through this one frame (the calibration itself gives every view its own
        pose; the difference is what the views' poses absorbed).
    """
    p_lens = np.vstack([transform_points(T, x) for T, x in zip(T_lens_rig, X, strict=True)])
    p_fit = np.vstack([transform_points(T, x) for T, x in zip(res.T_cam_target, X, strict=True)])
    uv_all = np.vstack(uv)
    ao = absolute_orientation(p_fit, p_lens, method="svd")
    if not ao.success:
        raise ConfigError("calibration", "views", f"the fitted camera's frame is undetermined: {ao.message}")
    rvec, tvec = cv2.solvePnPRefineLM(p_lens, uv_all, res.K, res.dist, cv2.Rodrigues(ao.R)[0],
                                      ao.t.reshape(3, 1).copy())
    T_fit_lens = homogeneous(cv2.Rodrigues(rvec)[0], tvec.ravel())
    e = np.linalg.norm(res.camera.project(transform_points(T_fit_lens, p_lens)) - uv_all, axis=1)
    return T_fit_lens, float(np.sqrt(np.mean(e**2)))


def fit_refractive(central, port: FlatPort, X, uv, noise_px: float, start_offset_m: float, rng):
    """The refractive model (:func:`bench.camera.refractive.calibrate_refractive`, lens and port free) of the views
    with ``noise_px`` of Gaussian pixel noise, started from the central fit ``central`` and the port with its
    lens-to-glass distance ``start_offset_m`` off (no tilt); returns ``(result, noisy pixels)``."""
    from bench.camera.refractive import calibrate_refractive, refractive_start

    noisy = [u + noise_px * rng.standard_normal(u.shape) for u in uv]
    start = port.centred(start_offset_m, keep_tilt=False)
    lens0, T0 = refractive_start(central.camera, central.T_cam_target, start)
    # glass and water with the index of air: no port to calibrate (its distance and tilt change nothing)
    vanished = port.n_water == port.n_air and port.n_glass == port.n_air
    return calibrate_refractive(X, noisy, lens0, start, T0, fix_port=vanished), noisy


def refractive_frame(camera, T_lens_rig, X, uv) -> np.ndarray:
    """``T_fit_lens`` (4, 4) of a fitted refractive camera: the rig corners at their true lens-frame positions, all
    views together, by least squares on their reprojection through it (what a mount calibration would absorb)."""
    import scipy.optimize
    from scipy.spatial.transform import Rotation

    p = np.vstack([transform_points(T, x) for T, x in zip(T_lens_rig, X, strict=True)])
    target = np.vstack(uv)

    def res(x):
        return (camera.project(Rotation.from_rotvec(x[:3]).apply(p) + x[3:]) - target).ravel()

    x = scipy.optimize.least_squares(res, np.zeros(6)).x
    return homogeneous(Rotation.from_rotvec(x[:3]).as_matrix(), x[3:])


def image_grid(lens: CameraModel, n) -> np.ndarray:
    """Pixels (n_u n_v, 2) on a regular grid over the whole image (pixel centres 0 .. W-1, 0 .. H-1)."""
    u = np.linspace(0.0, lens.width - 1.0, n[0])
    v = np.linspace(0.0, lens.height - 1.0, n[1])
    return np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)


def true_points(lens: CameraModel, port: FlatPort, uv, z):
    """Points (N, 3) in the lens frame seen by pixels ``uv`` at depth ``z`` (m): lens ray, port, water ray."""
    o, w, ok = trace_rays(lens.unproject(uv), port)
    if not np.all(ok):
        raise ValueError(f"{np.count_nonzero(~ok)} image rays miss the port or are totally reflected")
    lam = (z - o[:, 2]) / w[:, 2]
    if np.any(lam <= 0):
        raise ValueError(f"depth {z} m lies inside the housing for some rays")
    return o + lam[:, None] * w


def model_errors(fit: CameraModel, T_fit_lens, uv, p_lens):
    """Reprojection error (px) and object-space error (m) of the fitted model for points seen at pixels ``uv``.

    The object-space error is the distance of each true point from the fitted camera's ray through its pixel.
    """
    e_px = np.linalg.norm(fit.project(transform_points(T_fit_lens, p_lens)) - uv, axis=1)
    T_lens_fit = invert(T_fit_lens)
    d = fit.unproject(uv) @ T_lens_fit[:3, :3].T
    e_m = np.linalg.norm(np.cross(p_lens - T_lens_fit[:3, 3], d), axis=1)
    return e_px, e_m


def ok_window(distances, err, threshold):
    """``(from, to)`` (m): the span of working distances around the smallest error where ``err <= threshold``.

    Crossings are interpolated linearly in log(distance) and log(error); an edge that reaches the end of the evaluated
    range is that end. ``(nan, nan)`` when no distance meets the threshold.
    """
    d, e = np.asarray(distances, float), np.asarray(err, float)
    ok = e <= threshold
    if not np.any(ok):
        return np.nan, np.nan
    i = int(np.argmin(e))
    lo, hi = i, i
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    while hi < len(d) - 1 and ok[hi + 1]:
        hi += 1

    def cross(a, b):  # a within, b beyond the threshold
        t = (np.log(threshold) - np.log(e[a])) / (np.log(e[b]) - np.log(e[a]))
        return float(np.exp(np.log(d[a]) + t * (np.log(d[b]) - np.log(d[a]))))

    return (float(d[0]) if lo == 0 else cross(lo, lo - 1)), (float(d[-1]) if hi == len(d) - 1 else cross(hi, hi + 1))


def _coverage(uv_calib, size) -> float:
    """Fraction of the image area inside the convex hull of the calibration corners."""
    hull = cv2.convexHull(np.vstack(uv_calib).astype(np.float32))
    return float(cv2.contourArea(hull)) / (size[0] * size[1])


def _dist_key(d):
    return f"{d:g}".replace(".", "p") + "m"


def _distances(cfg):
    e = cfg["evaluation"]
    d = np.geomspace(e["distance_min_m"], e["distance_max_m"], e["distances"])
    D = cfg["calibration"]["distance_m"]
    if e["distance_min_m"] < D < e["distance_max_m"] and not np.any(np.isclose(d, D)):
        d = np.sort(np.append(d, D))
    return d


def run(cfg: dict, out_dir: Path, verbose: bool = True) -> Path:
    from bench.sim.scenes.rig import calibration_rig

    t_all = time.perf_counter()
    src = cfg["_file"]
    lens, port0 = _optics(cfg)
    cases = _check(cfg, port0)
    calib, thr = cfg["calibration"], cfg["threshold"]
    rig = calibration_rig()
    distances = _distances(cfg)
    uv_grid = image_grid(lens, cfg["evaluation"]["grid"])
    near, far = _dist_key(distances[0]), _dist_key(distances[-1])
    cols = ["alignment", "lens_to_glass_mm", "distance_m", "rms_px", "max_px", "rms_mm", "max_mm",
            "exceeds_threshold", "refractive_rms_px", "refractive_max_px", "central_noisy_rms_px"]
    refr_cfg = cfg["refractive"]
    table = {c: [] for c in cols}
    ccols = ["alignment", "lens_to_glass_mm", "views", "points", "calib_rms_px", "iterations", "fx_px", "fy_px",
             "cx_px", "cy_px", "k1", "k2", "p1", "p2", "k3", "centre_offset_axial_mm", "centre_offset_lateral_mm",
             "centre_rotation_deg", "paraxial_centre_axial_mm", "frame_reproj_rms_px", "calib_coverage",
             "polynomial_ok_from_m", "polynomial_ok_to_m"]
    ctable = {c: [] for c in ccols}
    metrics, timings = {"threshold_px": thr["px"]}, {"calibration_s": 0.0, "evaluation_s": 0.0}
    for n_case, (align, d0, port) in enumerate(cases):
        s = f"d0_{d0:g}mm_{align}".replace(".", "p")
        if verbose:
            print(f"\rflat-port study: case {n_case + 1}/{len(cases)} ({s})", end="", file=sys.stderr)
        t0 = time.perf_counter()
        rng = np.random.default_rng(cfg["seed"])  # the same campaign for every port
        T_lens_rig, X, uv = rig_views(lens, port, rig, calib, rng, source=src)
        res = fit_central_model(lens, port, T_lens_rig, X, uv, calib["k3"])
        if not res.success:
            raise ConfigError(src, "calibration", f"the Heikkilä fit failed for {s}: {res.message}")
        T_fit_lens, frame_rms = fitted_frame(res, T_lens_rig, X, uv)
        refr = None
        if refr_cfg["enabled"]:
            refr, noisy = fit_refractive(res, port, X, uv, refr_cfg["noise_px"], refr_cfg["start_offset_mm"] * 1e-3,
                                         np.random.default_rng([cfg["seed"], n_case, 31]))
            if not refr.success:
                raise ConfigError(src, "refractive", f"the refractive fit failed for {s}: {refr.message}")
            T_refr_lens = refractive_frame(refr.camera, T_lens_rig, X, noisy)
            res_n = fit_central_model(lens, port, T_lens_rig, X, noisy, calib["k3"])  # the same noise, central
            if not res_n.success:
                raise ConfigError(src, "refractive", f"the Heikkilä fit of the noisy views failed for {s}: "
                                                     f"{res_n.message}")
            T_n_lens, _ = fitted_frame(res_n, T_lens_rig, X, noisy)
        timings["calibration_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        fit = res.camera
        rms_px, max_px, rms_mm, max_mm, r_rms, r_max, c_rms = [], [], [], [], [], [], []
        for z in distances:
            try:
                p_lens = true_points(lens, port, uv_grid, z)
            except ValueError as exc:
                raise ConfigError(src, "evaluation.distance_min_m", f"{s}: {exc}") from None
            e_px, e_m = model_errors(fit, T_fit_lens, uv_grid, p_lens)
            if not (np.all(np.isfinite(e_px)) and np.all(np.isfinite(e_m))):
                raise ConfigError(src, "evaluation.grid", f"{s}: the fitted model cannot be inverted over the whole "
                                                          f"image at {z:g} m")
            rms_px.append(float(np.sqrt(np.mean(e_px**2))))
            max_px.append(float(e_px.max()))
            if refr is not None:
                e_r = np.linalg.norm(refr.camera.project(transform_points(T_refr_lens, p_lens)) - uv_grid, axis=1)
                r_rms.append(float(np.sqrt(np.mean(e_r**2))))
                r_max.append(float(e_r.max()))
                c_rms.append(float(np.sqrt(np.mean(model_errors(res_n.camera, T_n_lens, uv_grid, p_lens)[0] ** 2))))
            else:
                r_rms.append(float("nan"))
                r_max.append(float("nan"))
                c_rms.append(float("nan"))
            rms_mm.append(float(1e3 * np.sqrt(np.mean(e_m**2))))
            max_mm.append(float(1e3 * e_m.max()))
        stat = np.array(rms_px if thr["statistic"] == "rms" else max_px)
        lo, hi = ok_window(distances, stat, thr["px"])
        for i, z in enumerate(distances):
            for c, v in zip(cols, (align, d0, float(z), rms_px[i], max_px[i], rms_mm[i], max_mm[i],
                                   int(stat[i] > thr["px"]), r_rms[i], r_max[i], c_rms[i]), strict=True):
                table[c].append(v)
        timings["evaluation_s"] += time.perf_counter() - t0
        T_lens_fit = invert(T_fit_lens)
        c_par = paraxial_centre(port)
        dist = res.dist
        row = {"alignment": align, "lens_to_glass_mm": d0, "views": len(X), "points": int(sum(len(x) for x in X)),
               "calib_rms_px": res.rms_px, "iterations": res.iterations, "fx_px": res.K[0, 0], "fy_px": res.K[1, 1],
               "cx_px": res.K[0, 2], "cy_px": res.K[1, 2], "k1": dist[0], "k2": dist[1], "p1": dist[2],
               "p2": dist[3], "k3": dist[4], "centre_offset_axial_mm": 1e3 * T_lens_fit[2, 3],
               "centre_offset_lateral_mm": 1e3 * float(np.hypot(T_lens_fit[0, 3], T_lens_fit[1, 3])),
               "centre_rotation_deg": float(np.rad2deg(rotation_angle(T_lens_fit[:3, :3]))),
               "paraxial_centre_axial_mm": 1e3 * c_par[2], "frame_reproj_rms_px": frame_rms,
               "calib_coverage": _coverage(uv, lens.size), "polynomial_ok_from_m": lo, "polynomial_ok_to_m": hi}
        for c in ccols:
            ctable[c].append(row[c])
        i_cal = int(np.argmin(np.abs(distances - calib["distance_m"])))
        metrics.update({
            f"calib_rms_px_{s}": res.rms_px, f"rms_px_at_calib_{s}": rms_px[i_cal],
            f"rms_px_at_{near}_{s}": rms_px[0], f"max_px_at_{near}_{s}": max_px[0],
            f"rms_px_at_{far}_{s}": rms_px[-1], f"max_px_at_{far}_{s}": max_px[-1],
            f"rms_mm_at_{near}_{s}": rms_mm[0], f"rms_mm_at_{far}_{s}": rms_mm[-1],
            f"polynomial_ok_from_m_{s}": lo, f"polynomial_ok_to_m_{s}": hi,
            f"refractive_needed_below_m_{s}": lo, f"refractive_needed_above_m_{s}": hi,
            f"refractive_needed_everywhere_{s}": float(np.isnan(lo)),
            f"centre_offset_axial_mm_{s}": row["centre_offset_axial_mm"],
            f"centre_offset_lateral_mm_{s}": row["centre_offset_lateral_mm"],
            f"centre_rotation_deg_{s}": row["centre_rotation_deg"],
            f"paraxial_centre_axial_mm_{s}": row["paraxial_centre_axial_mm"],
            f"calib_coverage_{s}": row["calib_coverage"], f"frame_reproj_rms_px_{s}": frame_rms,
        })
        if refr is not None:
            metrics.update({
                f"refractive_rms_px_at_calib_{s}": r_rms[i_cal], f"refractive_rms_px_at_{near}_{s}": r_rms[0],
                f"refractive_rms_px_at_{far}_{s}": r_rms[-1],
                f"refractive_d0_err_mm_{s}": 1e3 * abs(refr.camera.port.d0 - port.axial_d0),
                f"refractive_calib_rms_px_{s}": refr.rms_px,
                f"central_noisy_rms_px_at_{near}_{s}": c_rms[0], f"central_noisy_rms_px_at_{far}_{s}": c_rms[-1],
                f"central_noisy_rms_px_at_calib_{s}": c_rms[i_cal],
            })
    if verbose:
        print(file=sys.stderr)
    tables = {TABLE: table, CALIB_TABLE: ctable}
    artifacts = {}
    write_table_csv(out_dir / f"{TABLE}.csv", table)
    write_table_csv(out_dir / f"{CALIB_TABLE}.csv", ctable)
    artifacts.update({f"{TABLE}_csv": f"{TABLE}.csv", f"{CALIB_TABLE}_csv": f"{CALIB_TABLE}.csv"})
    if cfg["outputs"]["plots"]:
        tilt = next((np.rad2deg(port.tilt) for a, _, port in cases if a == "tilted"), (0.0, 0.0))
        artifacts["flatport_error_plot"] = plot_study(table, cfg, out_dir / f"{TABLE}.png", tilt)
    timings["total_s"] = time.perf_counter() - t_all
    path = write_result(out_dir, cfg["name"], cfg["seed"], metrics, tables, timings, artifacts)
    if verbose:
        print(format_summary(table, ctable, cfg, distances))
    return path


# ------------------------------------------------------------------------------------------------ report


def plot_study(table: dict, cfg: dict, path, tilt_deg=(0.0, 0.0)) -> str:
    """Error vs working distance (log-log), one curve per lens-to-glass distance, one column per port alignment
    (``tilt_deg``: the tilted case's port tilt about the camera x and y axes, for the title)."""
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    plt = headless_pyplot()

    al = np.asarray(table["alignment"])
    aligns = [a for a in ALIGNMENTS if a in set(al.tolist())]
    d0 = np.asarray(table["lens_to_glass_mm"], float)
    z = np.asarray(table["distance_m"], float)
    D, dr = cfg["calibration"]["distance_m"], cfg["calibration"]["depth_range_m"]
    thr, stat = cfg["threshold"]["px"], cfg["threshold"]["statistic"]
    fig, axes = plt.subplots(2, len(aligns), figsize=(5.6 * len(aligns), 7.6), squeeze=False, sharex=True)
    for j, a in enumerate(aligns):
        for k, d in enumerate(sorted(set(d0[al == a].tolist()))):
            sel = (al == a) & (d0 == d)
            order = np.argsort(z[sel])
            x = z[sel][order]
            color = f"C{k}"
            for row, key in enumerate(("px", "mm")):
                ax = axes[row, j]
                ax.plot(x, np.asarray(table[f"rms_{key}"])[sel][order], "o-", ms=3, color=color,
                        label=f"d0 = {d:g} mm (RMS)")
                ax.plot(x, np.asarray(table[f"max_{key}"])[sel][order], "--", lw=0.9, color=color)
                if key == "px" and np.any(np.isfinite(np.asarray(table["refractive_rms_px"], float)[sel])):
                    ax.plot(x, np.asarray(table["refractive_rms_px"], float)[sel][order], "s:", ms=3, color=color,
                            label=f"d0 = {d:g} mm, refractive (RMS)")
        for row in range(2):
            ax = axes[row, j]
            ax.axvspan(D - dr, D + dr, color="0.85", zorder=0)
            ax.axvline(D, color="0.5", lw=0.8)
            ticks = [x for x in (0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 2.0, 3.0, 5.0, 10.0, 20.0, 50.0)
                     if z.min() * 0.99 <= x <= z.max() * 1.01]
            ax.set(xscale="log", yscale="log", xticks=ticks)
            ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.grid(alpha=0.3, which="both")
        axes[0, j].axhline(thr, color="k", ls=":", lw=1.2, label=f"threshold {thr:g} px ({stat})")
        what = "port normal on the optical axis" if a == "aligned" else (
            f"port tilted {tilt_deg[0]:.2f} / {tilt_deg[1]:.2f} deg about x / y")
        axes[0, j].set_title(f"{a}: {what}", fontsize=10)
        axes[0, j].set_ylabel("reprojection error over the image (px)")
        axes[1, j].set(ylabel="object-space error (mm)", xlabel="working distance z (m, lens frame)")
        axes[0, j].legend(fontsize=7, loc="best")
    refr = cfg["refractive"]
    extra = (f"\nsquares, dotted: the refractive model calibrated from the same views + {refr['noise_px']:g} px noise"
             if refr["enabled"] else "")
    fig.suptitle(f"Heikkilä model{' + k3' if cfg['calibration']['k3'] else ''} calibrated at {D:g} +- {dr:g} m "
                 f"(grey) behind a flat port: RMS (o-) and max (--) over the image{extra}", fontsize=10)
    fig.tight_layout()
    atomic_save_figure(fig, path, dpi=110)
    return Path(path).name


def format_summary(table: dict, ctable: dict, cfg: dict, distances) -> str:
    thr, stat = cfg["threshold"]["px"], cfg["threshold"]["statistic"]
    D = cfg["calibration"]["distance_m"]
    i_cal = int(np.argmin(np.abs(distances - D)))
    n = len(distances)
    head = (f"{'alignment':<9}{'d0 mm':>7}{'calib px':>10}{'centre mm':>11}"
            f"{f'@{distances[0]:g}m px':>12}{f'@{distances[i_cal]:g}m px':>12}{f'@{distances[-1]:g}m px':>11}"
            f"{'max@far px':>11}{f'@{distances[-1]:g}m mm':>11}   polynomial ok (m)")
    lines = [f"Flat-port study: Heikkilä fit calibrated at {D:g} m; image RMS error vs working distance "
             f"(threshold {thr:g} px, {stat})", head]
    for r in range(len(ctable["alignment"])):
        rp = np.asarray(table["rms_px"][r * n:(r + 1) * n])
        lo, hi = ctable["polynomial_ok_from_m"][r], ctable["polynomial_ok_to_m"][r]
        ok = "never (refractive model needed)" if np.isnan(lo) else f"{lo:.3g} .. {hi:.3g}"
        lines.append(f"{ctable['alignment'][r]:<9}{ctable['lens_to_glass_mm'][r]:>7g}{ctable['calib_rms_px'][r]:>10.4f}"
                     f"{ctable['centre_offset_axial_mm'][r]:>11.2f}{rp[0]:>12.3f}{rp[i_cal]:>12.3f}{rp[-1]:>11.3f}"
                     f"{table['max_px'][(r + 1) * n - 1]:>11.3f}{table['rms_mm'][(r + 1) * n - 1]:>11.3f}   {ok}")
    if cfg["refractive"]["enabled"]:
        lines.append(f"The same views + {cfg['refractive']['noise_px']:g} px noise: image RMS error (px) of the "
                     f"refractive model and of the Heikkilä fit at {distances[0]:g} / {distances[i_cal]:g} / "
                     f"{distances[-1]:g} m")
        lines.append(f"{'alignment':<9}{'d0 mm':>7}{'refractive':>36}{'Heikkila':>36}")
        for r in range(len(ctable["alignment"])):
            rr = np.asarray(table["refractive_rms_px"][r * n:(r + 1) * n], float)
            cc = np.asarray(table["central_noisy_rms_px"][r * n:(r + 1) * n], float)
            lines.append(f"{ctable['alignment'][r]:<9}{ctable['lens_to_glass_mm'][r]:>7g}"
                         f"{rr[0]:>12.3f}{rr[i_cal]:>12.3f}{rr[-1]:>12.3f}{cc[0]:>12.3f}{cc[i_cal]:>12.3f}"
                         f"{cc[-1]:>12.3f}")
    return "\n".join(lines)
