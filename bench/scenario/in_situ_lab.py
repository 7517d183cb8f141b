"""The in-situ scenario's lab step (the pipeline's, on the dataset): the arm from the tracker points, the camera from
the rig views (central, or refractive: :mod:`bench.camera.refractive`), the mount by AX = XB, and the priors of
refine 'joints' (the calibrations' covariances, the rig's stated tolerances through them). It writes the calibrated
files (``camera.yaml``, ``robot.yaml``, ``calibration_priors.yaml``) that ``bench locate`` reads.

Nothing here reads the truth: only the dataset's public part and the scenario's pipeline settings.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bench.camera.calibrate_dataset import load_target, load_target_tolerance
from bench.camera.calibration import calibrate_camera
from bench.camera.corners import extract_corners
from bench.camera.io import write_camera_yaml
from bench.errors import ConfigError
from bench.geometry.transforms import homogeneous, invert, rot_z, transform_points
from bench.robot.calibration_file import write_calibrated_robot
from bench.robot.identifiability import closed_form_reduction
from bench.robot.identification import identify_iterative
from bench.robot.orientation import link5_frame
from bench.vision.handeye import hand_eye_axxb, resolve_target_symmetry

DEG = np.pi / 180


@dataclass(frozen=True)
class _VirtualCalibration:
    """A refractive calibration seen as the central calibration of its virtual pinhole
    (:meth:`~bench.camera.refractive.RefractiveCamera.virtual_camera`): ``K``, ``dist`` (zero), ``T_cam_target``,
    and the covariance of ``fx fy cx cy k1 k2 p1 p2`` - the lens's scaled by the port's paraxial magnification - for
    the lab priors of the joint bundle (which sees the refractive coordinates through that pinhole, and corrects them
    with a first-order distortion of its own under that prior)."""

    K: np.ndarray
    dist: np.ndarray
    T_cam_target: np.ndarray
    parameter_names: tuple
    covariance: np.ndarray
    dist_equivalent: np.ndarray  # the lens's k1 k2 p1 p2 in the pinhole's coordinates (first order): mag^2, mag^4, mag

    @classmethod
    def of(cls, r):
        from bench.camera.refractive import virtual_scale

        cam = r.camera.virtual_camera()
        names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
        idx = [r.parameter_names.index(n) for n in names]
        S = np.diag(virtual_scale(r.camera.port))  # the pinhole's equivalent (first-order) intrinsics and distortion
        C = S @ r.covariance[np.ix_(idx, idx)] @ S
        C = 0.5 * (C + C.T)
        return cls(cam.K, cam.dist, r.T_cam_target, names, C, np.diag(S)[4:] * r.camera.lens.dist[:4])


def rig_corners(ds, geometry, extractor: str, role: str, need: int = 3):
    """``(object points, pixels, views, size)`` of the rig's corners in the dataset's views of ``role`` where the
    ``extractor`` finds the rig, ``size`` the last of those images' ``(width, height)``; fewer than ``need`` views is
    a one-line error."""
    Xs, uvs, used, size = [], [], [], None
    for v in (v for v in ds.views if v.role == role):
        img = v.image()
        res = extract_corners(img, geometry, extractor)
        if res.success:
            Xs.append(res.object_points)
            uvs.append(res.uv)
            used.append(v)
            size = (img.shape[1], img.shape[0])
    if len(used) < need:
        raise ConfigError(ds.root, f"{role} views", f"the rig was found in {len(used)} views (need >= {need})")
    return Xs, uvs, used, size


def _calibrate_lens_in_air(ds, geometry, cfg):
    """The lens from the rig views in air (role ``rig_air``, ``lab.rig_in_air``): a central fit, then the lens behind
    the housing's glass with air outside (a slab: its distance from the lens does not matter, the port is held at the
    datasheet's) - ``(mean (8,), covariance (8, 8))`` of :data:`bench.camera.refractive.LENS_NAMES`, the water
    calibration's prior; None without air views."""
    from bench.camera.io import read_housing_yaml
    from bench.camera.refractive import LENS_NAMES, calibrate_refractive, refractive_start

    if not any(v.role == "rig_air" for v in ds.views):
        return None
    Xs, uvs, used, _ = rig_corners(ds, geometry, cfg["pipeline"]["extractor"], "rig_air")
    size = (used[0].image().shape[1], used[0].image().shape[0])
    c = calibrate_camera(Xs, uvs, size, model="heikkila")
    if not c.success:
        raise ConfigError(ds.root, "rig_air views", f"camera calibration in air failed: {c.message}")
    housing, _ = read_housing_yaml(ds.root / "housing.yaml")
    slab = replace(housing, n_water=housing.n_air)
    lens0, T0 = refractive_start(c.camera, c.T_cam_target, slab)
    r = calibrate_refractive(Xs, uvs, lens0, slab, T0, fix_port=True)
    if not r.success:
        raise ConfigError(ds.root, "rig_air views", f"lens calibration in air failed: {r.message}")
    idx = [r.parameter_names.index(n) for n in LENS_NAMES]
    return r.parameters[idx], r.covariance[np.ix_(idx, idx)]


def _calibrate_refractive(ds, cal, Xs, uvs, raise_on_failure=True, air=None):
    """The lens and the flat port from the rig views (:func:`bench.camera.refractive.calibrate_refractive`), started
    from the central calibration ``cal`` of the same views and the housing's datasheet (``housing.yaml``), the lens
    under ``air`` (the lens calibrated in air: mean, covariance) when given; its working range is the rig corners'
    median depth. The datasheet's lens-to-glass distance is a prior within its
    stated tolerance: rig views at one range hardly see it (measured: seed 1's nine views leave it at +-0.3 m
    without the prior). None (or a one-line error) when it fails."""
    from bench.camera.io import read_housing_yaml
    from bench.camera.refractive import RefractiveCamera, calibrate_refractive, refractive_start, with_lens_parameters

    housing, d0_sigma = read_housing_yaml(ds.root / "housing.yaml")
    lens0, T0 = refractive_start(cal.camera, cal.T_cam_target, housing)
    if air is not None:  # start from the air lens, the poses from the central fit
        lens0 = with_lens_parameters(lens0, air[0])
    r = calibrate_refractive(Xs, uvs, lens0, housing, T0, d0_sigma_m=d0_sigma, lens_prior=air)
    if not r.success:
        if raise_on_failure:
            raise ConfigError(ds.root, "rig views", f"refractive camera calibration failed: {r.message}")
        return None
    z = float(np.median(np.concatenate([transform_points(T, X)[:, 2] for T, X in zip(r.T_cam_target, Xs,
                                                                                       strict=True)])))
    cam = RefractiveCamera(r.camera.lens.replace(name="lens (refractive calibration)"), r.camera.port, z,
                           name="refractive camera (lab)")
    return replace(r, camera=cam)


def _tolerance_covariance(geometry, tolerance, Xs, uvs, size, cal, he, T_base_l5, mount_nominal, S,
                          draws, refr=None, ds=None, air=None, k3=False) -> tuple:
    """What the rig's stated tolerances leave in the lab results: the second moment (14, 14) of the deviations of
    ``fx, fy, cx, cy`` (px), ``k1, k2, p1, p2`` and the mount (right perturbation: rotation vector rad, translation
    m) over calibrations of the same detections against perturbed rigs
    (:func:`bench.camera.target_tolerance.consider_covariance`), and the number of runs that succeeded. With
    ``k3`` (a central calibration that fitted it) k3 follows ``p2``: (15, 15)."""
    from bench.camera.target_tolerance import consider_covariance
    from bench.geometry.quaternion import matrix_to_rotation_vector

    def lab_vector(c):  # a refractive calibration: its lens's distortion, as its virtual pinhole sees it
        return np.r_[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], getattr(c, "dist_equivalent", c.dist[:5 if k3 else 4])]

    v0, M_inv = lab_vector(cal if refr is None else _VirtualCalibration.of(refr)), invert(he.T_mount_cam)

    def solve(Xs_m):
        c = calibrate_camera(Xs_m, uvs, size, model="heikkila", k3=cal.dist[4] != 0.0)
        if not c.success:
            return None
        if refr is not None:  # the refractive camera, started from this central fit as in the lab
            r = _calibrate_refractive(ds, c, Xs_m, uvs, raise_on_failure=False, air=air)
            if r is None:
                return None
            c = _VirtualCalibration.of(r)
        T_ct, _ = resolve_target_symmetry(T_base_l5, c.T_cam_target, mount_nominal, [S])
        h = hand_eye_axxb(T_base_l5, T_ct)
        if not h.success:
            return None
        D = M_inv @ h.T_mount_cam
        return np.r_[lab_vector(c) - v0, matrix_to_rotation_vector(D[:3, :3]), D[:3, 3]]

    return consider_covariance(geometry, tolerance, Xs, solve, draws)


def refines_k3(pipeline: dict) -> bool:
    """Whether the in-situ kind's joint bundle refines the lens's k3 (``pipeline.refine_k3``): with the distortion
    refined and the central camera model (a refractive camera's lens is behind the port). Keys absent in an older
    run's settings take the kind's defaults."""
    return (pipeline.get("refine_k3", False) and pipeline.get("refine_distortion", True)
            and pipeline.get("camera_model", "central") == "central")


def lab_k3_prior(cal, pipeline: dict) -> bool:
    """Whether the priors carry the lab's own k3 in the distortion block (5 x 5, with its cross-covariances): the
    joint bundle refines the distortion and k3 (:func:`refines_k3`) and the lab's central calibration fitted it
    (``pipeline.lab_k3``, without the rig's refinement, whose fit holds k3 at zero)."""
    return refines_k3(pipeline) and "k3" in cal.parameter_names


def _lab_priors(cal, he, n_views, cfg, tolerance_cov=None) -> dict:
    """The lab calibrations' covariances for refine 'joints' (:func:`bench.vision.joint_bundle.read_priors`'s
    names): the camera calibration's own block of ``fx fy cx cy`` (and ``k1 k2 p1 p2`` with
    ``pipeline.refine_distortion``; with ``pipeline.refine_k3`` also k3: the lab's own k3 with its
    cross-covariances when it fitted it, :func:`lab_k3_prior`, else an independent sd
    :data:`~bench.vision.joint_bundle.K3_PRIOR_SD`); the mount's from the AX = XB residuals, rms^2 / n per axis (it
    gives no covariance); plus the rig tolerances' consider covariance (14, 14 - 15, 15 with the lab's k3) when
    given."""
    k3 = lab_k3_prior(cal, cfg["pipeline"])
    names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2") + (("k3",) if k3 else ())
    n = len(names)  # the camera's parameters, then the mount's six
    idx = [cal.parameter_names.index(p) for p in names]
    C = np.zeros((n + 6, n + 6))
    C[:n, :n] = cal.covariance[np.ix_(idx, idx)]
    C[n:, n:] = np.diag(np.r_[np.full(3, he.rms_rot_rad**2), np.full(3, he.rms_trans_m**2)] / n_views)
    tol = tolerance_cov is not None  # the noise covariances have no intrinsics-mount cross term
    if tol:
        C = C + tolerance_cov
    out = {"cov_K": C[:4, :4], "cov_mount": C[n:, n:], "cov_K_mount": C[:4, n:] if tol else None}
    if cfg["pipeline"]["refine_distortion"]:
        out.update(cov_dist=C[4:n, 4:n], cov_K_dist=C[:4, 4:n], cov_dist_mount=C[4:n, n:] if tol else None)
        if refines_k3(cfg["pipeline"]) and not k3:  # the lab held k3 at zero: a wide independent prior
            from bench.vision.joint_bundle import K3_PRIOR_SD

            out["k3_sd"] = K3_PRIOR_SD
    return out


def calibrate_lab(ds, robot, cfg, out):
    """The pipeline's lab step on the dataset: arm (tracker), camera (rig), mount (AX = XB); writes calibrated files."""
    t0 = time.perf_counter()
    red = closed_form_reduction(robot)
    sigma = cfg["lab"]["tracker_sigma_mm"] * 1e-3
    ident = identify_iterative(robot, ds.tracker["q"], ds.tracker["p"], red, sigma=sigma)
    if not ident.success:
        raise ConfigError(ds.root / "tracker.csv", "<identification>", ident.message)
    eps_hat = ident.eps
    t_arm = time.perf_counter() - t0
    geometry = load_target(ds.root / "target.yaml")
    Xs, uvs, used, _ = rig_corners(ds, geometry, cfg["pipeline"]["extractor"], "rig")
    size = (used[0].image().shape[1], used[0].image().shape[0])
    cal = calibrate_camera(Xs, uvs, size, model="heikkila", k3=cfg["pipeline"]["lab_k3"])
    if not cal.success:
        raise ConfigError(ds.root, "rig views", f"camera calibration failed: {cal.message}")
    if cfg["pipeline"]["refine_rig"]:  # the printout's structure with the camera; the nominal fit if that fails
        from bench.camera.target_refinement import calibrate_camera_refining_rig

        refined = calibrate_camera_refining_rig(Xs, uvs, size, model="heikkila").calibration
        cal = refined if refined.success else cal
    refr = air = None
    if cfg["pipeline"]["camera_model"] == "refractive":
        air = _calibrate_lens_in_air(ds, geometry, cfg)
        refr = _calibrate_refractive(ds, cal, Xs, uvs, air=air)
    t_cam = time.perf_counter() - t0 - t_arm
    T_base_l5 = np.stack([link5_frame(robot, v.q, eps_hat) for v in used])
    # the rig looks the same after a half turn about the horizontal bisector of its boards: make its frame consistent
    z_mid = float(np.mean(geometry.object_points()[:, 2]))
    S = homogeneous(np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]), [0.0, 0.0, 2 * z_mid])
    mount_nominal = homogeneous(rot_z(cfg["truth"]["mount_roll_deg"] * DEG),  # a 3-vector (the kind's model)
                                np.asarray(cfg["truth"]["mount_mm"], dtype=float) * 1e-3)
    T_cam_target, _ = resolve_target_symmetry(T_base_l5, (cal if refr is None else refr).T_cam_target,
                                              mount_nominal, [S])
    he = hand_eye_axxb(T_base_l5, T_cam_target)
    if not he.success:
        raise ConfigError(ds.root, "rig views", f"mount calibration failed: {he.message}")
    out = Path(out)
    write_camera_yaml(out / "camera.yaml", cal.camera if refr is None else refr.camera)
    # the calibrations' covariances, refine 'joints' refines intrinsics, mount (and distortion) under them
    notes = (f"camera calibration covariance (fx fy cx cy [k1 k2 p1 p2 [k3]], px^2); mount: AX = XB residuals^2 / "
             f"{len(used)} views (rad^2, m^2)")
    if refr is not None:
        notes = (f"refractive camera: its virtual pinhole's fx fy cx cy [k1 k2 p1 p2] from the lens's calibration "
                 f"covariance (px^2); mount: AX = XB residuals^2 / {len(used)} views (rad^2, m^2)")
    tol_cov, tol_draws = None, 0
    tolerance = load_target_tolerance(ds.root / "target.yaml")
    if tolerance is not None and tolerance.any and cfg["pipeline"]["target_tolerance"]:
        tol_cov, tol_draws = _tolerance_covariance(
            geometry, tolerance, Xs, uvs, size, cal, he, T_base_l5, mount_nominal, S,
            cfg["pipeline"]["tolerance_draws"], refr, ds, air,
            k3=refr is None and lab_k3_prior(cal, cfg["pipeline"]))
        notes += (f"; plus the rig's stated tolerances (target.yaml) through the calibration and AX = XB, "
                  f"{tol_draws} Monte Carlo draws" + ("" if air is None else " (the lens from the air views held at "
                                                                          "the nominal rig's)"))
    priors = _lab_priors(cal if refr is None else _VirtualCalibration.of(refr), he, len(used), cfg, tol_cov)
    from bench.vision.joint_bundle import priors_yaml_text

    (out / "calibration_priors.yaml").write_text(priors_yaml_text(notes=notes, **priors))
    write_calibrated_robot(out / "robot.yaml", ds.robot_path, robot, eps_hat, he.T_mount_cam,
                           notes=f"identified from {len(ds.tracker['q'])} tracker points; mount from {len(used)} rig "
                                 "views (AX = XB)")
    return {"eps": eps_hat, "identification": ident, "camera": cal, "refractive": refr, "mount": he,
            "rig_views_used": len(used),
            "priors": priors, "tolerance_draws": tol_draws,
            "rig_q": np.stack([v.q for v in used]), "T_cam_target": T_cam_target,
            "timings": {"arm_calibration_s": t_arm, "camera_calibration_s": t_cam,
                        "mount_calibration_s": time.perf_counter() - t0 - t_arm - t_cam}}
