"""Scenario kind ``in_situ``: the whole story of the thesis on the simulated TA-40 (``make demo``).

Simulation (``render``, also ``bench sim render``) writes one dataset, as a real campaign would:

1. lab - tracker points of the end effector (arm calibration) and views of the two-plane rig taken by the link-5
   camera at several arm poses (camera and camera-mount calibration);
2. site - the ROV parks the base at an unknown pose in front of a manifold panel, within the arm's reach; a reference
   view and surrounding views (baseline from Eq. 199 for the wanted depth resolution at the panel's range) make the
   survey, and the operator teaches a task: the tool on a valve handle (a frame of joint readings, role ``task``);
   the ROV then parks again (the base moves) and two new views are taken.

The dataset holds images, joint *readings*, tracker points and the *nominal* robot and camera files; ``truth/``
holds the true errors, base poses, mount, intrinsics, joint angles and panel features.

The pipeline (``run``) then uses only the public part: identification from the tracker points (Eq. 14 / LM), camera
calibration from the rig corners, the mount by AX = XB, the survey map and the localisation (section 3.9), and is
scored against the truth: ``base_pos_err_mm`` and ``base_rot_err_deg`` are the errors of the base's displacement
between the survey and the new parking (the site frame of the pipeline is the survey base frame). Finally the
pipeline re-targets the taught task from the located base (:mod:`bench.robot.task`: compensated IK on the
calibrated arm), the simulated servos drive the true arm to the commanded readings, and ``valve_tool_err_mm`` is the
distance of the true tool tip from the true handle centre (``valve_tool_err_uncompensated_mm``: the taught readings
replayed at the new parking, what happens without the in-situ calibration). The signed errors are metrics too:
``base_pos_err_{x,y,z}_mm`` and ``base_rot_err_{x,y,z}_deg`` (the estimate's translation less the truth's, and the
rotation vector of the estimate's rotation times the truth's inverse, in the survey base frame) and
``valve_tool_err_{x,y,z}_mm`` (the tool tip less the handle centre, world frame); ``bench budget`` pairs them seed
by seed.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import Field, model_validator

from bench.camera.flatport import FlatPort
from bench.camera.io import camera_yaml_text, housing_yaml_text, read_camera_yaml, write_camera_yaml
from bench.camera.model import CameraModel
from bench.camera.presets import load_preset
from bench.config import (
    ImagingParams,
    KeyProblem,
    NonNegFloat,
    NonNegInt,
    Number,
    PositiveFloat,
    PositiveInt,
    ScenarioBase,
    Section,
    Vec2,
    Vec3,
    about,
    at_least,
    at_most,
    section,
)
from bench.dataset import DatasetWriter, load_dataset
from bench.errors import ConfigError
from bench.geometry.quaternion import matrix_to_rotation_vector
from bench.geometry.transforms import homogeneous, invert, rot_x, rot_y, rot_z, transform_points
from bench.robot.calibration_file import write_calibrated_robot
from bench.robot.identifiability import closed_form_reduction
from bench.robot.ik import compensated_ik
from bench.robot.kinematics import ee_position, forward_kinematics
from bench.robot.model import load_robot, random_errors
from bench.robot.orientation import link5_frame
from bench.scenario.in_situ_lab import calibrate_lab
from bench.scenario.plan_memo import memoized
from bench.scenario.results import pose_errors, write_result, write_table_csv
from bench.scenario.scene_textures import naming_the_key, texture_paths
from bench.sim.imaging import draw_true_lens, profile_from_config, rig_errors, rig_target_yaml
from bench.sim.ins import vehicle_yaml_text
from bench.sim.optics_presets import optics_preset
from bench.vision.handeye import hand_eye_axxb
from bench.vision.insitu import twin_map_config
from bench.vision.locate_dataset import locate_dataset
from bench.vision.tilt import VEHICLE_FILE
from bench.vision.triangulation import required_baseline

SOURCES = {"kinematics": ("calibrated", "perfect"), "camera": ("calibrated", "perfect"),
           "encoders": ("real", "perfect"), "features": ("sift", "perfect")}
ENCODER_DEG = (Field(ge=0), at_most(5.0, "{v} deg is implausible for an encoder (the unit is deg)"))


class Truth(Section):
    error_trans_mm: NonNegFloat = 2.0
    error_rot_deg: NonNegFloat = 1.0
    mount_mm: Vec3 = [120.0, 0.0, 300.0]
    mount_roll_deg: float = 180.0
    mount_bias_mm: Vec3 = [2.0, -1.5, 3.0]
    mount_bias_deg: Vec3 = [0.5, -0.8, 1.0]
    focal_error_pct: NonNegFloat = 1.5
    principal_error_px: NonNegFloat = 4.0


class Camera(Section):
    preset: str = "air_webcam"
    supersample: PositiveInt = 2
    imaging: str = "realistic"
    imaging_off: list[str] = []
    imaging_params: ImagingParams = {}
    housing_tolerance_mm: Annotated[PositiveFloat, about(
        "the housing datasheet's tolerance (+-) on the lens-to-glass distance: housing.yaml states the true distance "
        "off by a draw within it (a drawing does not locate the lens's entrance pupil exactly)")] = 3.0


class Encoders(Section):
    noise_deg: Annotated[float, *ENCODER_DEG] = 0.002
    resolution_deg: Annotated[float, *ENCODER_DEG] = 0.001


class Lab(Section):
    tracker_poses: PositiveInt = 100
    tracker_sigma_mm: Annotated[float, Field(gt=0), at_most(50, "implausible: the unit is mm")] = 0.05
    rig_views: Annotated[int, Field(ge=1), at_least(3, "{v} views; the camera calibration needs the rig in at least 3")
                         ] = 10
    rig_distance_m: PositiveFloat = 0.9
    eye_base_m: Vec3 = [1.5, 0.7, 0.7]
    rig_in_air: Annotated[bool, about(
        "the rig also photographed in air (before the tank is flooded) from the same poses: views rigairNN, role "
        "rig_air - the lens's own calibration, which pipeline.camera_model=refractive starts from")] = False
    rig_extra_distances_m: Annotated[list[Annotated[Number, Field(gt=0.2, lt=3)]], about(
        "more rig views (lab.rig_views each) at these distances: a campaign over a range of distances, which a "
        "refractive camera model needs to see its port (rendered after the others: their draws do not move)")] = []


class Site(Section):
    panel_width_m: PositiveFloat = 1.2
    panel_height_m: PositiveFloat = 0.8
    standoff_m: PositiveFloat = 0.7
    panel_centre_m: Vec3 = [1.55, 0.45, 0.85]
    base_offset_m: NonNegFloat = 0.3
    base_rot_deg: NonNegFloat = 10.0
    parking_attempts: PositiveInt = 40
    water: Annotated[str, about("the water body (bench.sim.medium.WATER_PRESETS), or the camera preset's own")] = \
        "preset"
    placement: Annotated[Literal["panel", "eye"], about(
        "panel: the panel at panel_centre_m, the reference eye standoff_m in front of it; eye: the reference eye at "
        "eye_m (a point the arm reaches comfortably) and the panel standoff_m ahead of it (+x of the world)")] = "panel"
    eye_m: Vec3 = [1.05, 0.45, 1.0]
    textures: Annotated[dict, about("face -> image file (bench.scenario.scene_textures)")] = {}
    regions_m: Annotated[list[Vec2], Field(min_length=1), about(
        "[x, y] of each region's aim point from the panel centre in the panel's plane (x to the right as the arm "
        "sees it, y up): each region has its own reference, surrounding and locate views (regions after the "
        "first: views rK_ref, rK_surveyNN, rK_locateN), solved together by pipeline.refine=joints")] = [[0.0, 0.0]]
    region_views: Annotated[Literal["shifted", "aimed"], about(
        "how a region after the first is viewed: shifted, the first region's eyes moved in the panel's plane by the "
        "aim points' offset; aimed, the same eyes as the first region's, turned to the region's aim point (wider "
        "aim points within the arm's reach, oblique views)")] = "shifted"


class Vehicle(Section):
    ins: Annotated[bool, about(
        "the vehicle's INS writes gravity's direction in the base frame at both parkings (vehicle.yaml): the "
        "localisation's tilt check (bench.vision.tilt)")] = True
    tilt_sigma_deg: Annotated[PositiveFloat, at_most(5, "{v} deg is implausible for an INS"), about(
        "its roll / pitch accuracy, 1 sigma per axis (a fibre-optic gyrocompass: 0.01)")] = 0.01
    alignment_sigma_deg: Annotated[PositiveFloat, at_most(5, "{v} deg is implausible for a lab alignment"), about(
        "the lab's INS-to-base alignment, 1 sigma per axis")] = 0.05


class Survey(Section):
    depth_resolution_mm: PositiveFloat = 5.0
    directions: PositiveInt = 6
    offsets_mm: Annotated[list[Vec2], about("[x_mm, y_mm] pairs")] = []
    radius_limit_mm: Annotated[NonNegFloat, about(
        "> 0: the Eq. 199 radius capped at what the arm can sweep (0: no limit)")] = 0.0


class Task(Section):
    valve: str = "nearest"
    teach: bool = True


class Locate(Section):
    baseline_mm: PositiveFloat = 150.0
    baseline_direction_deg: Annotated[float, Field(ge=-180, le=180), about(
        "direction of the two locate eyes' baseline in the reference view's image plane, from the image's x (0, "
        "across the panel) towards image-up (90): the two views then differ by a turn about the axis perpendicular "
        "to it, and a camera knocked on its mount about any other axis makes them disagree (docs/integrity.md)")] = 0.0
    motion_m: NonNegFloat = 0.15
    motion_deg: NonNegFloat = 5.0


class Pipeline(Section):
    method: Literal["svd", "horn", "rodrigues"] = "svd"
    extractor: Literal["opencv", "thesis"] = "opencv"
    refine: Literal["none", "pose", "bundle", "joints"] = "bundle"
    locate: Annotated[Literal["two_view", "pnp"], about(
        "the localisation: the thesis's two locate views (kinematic triangulation, absolute orientation, RANSAC) or "
        "PnP of the first locate view against the map (bench.vision.insitu.locate_pnp; it refines its own pose, so "
        "refine must be none); the bound follows it")] = "two_view"
    ransac_iterations: PositiveInt = 100
    d_r_mm: PositiveFloat = 20.0
    r_lim: NonNegFloat = 0.1
    refine_rig: Annotated[bool, about(
        "the lab camera calibration also estimates the printed rig's structure (line offsets, bows, fold: "
        "bench.camera.target_refinement), else it trusts the nominal rig")] = False
    lab_k3: Annotated[bool, about(
        "the lab calibration's radial model: Heikkila's k1, k2 (p1, p2), and with lab_k3 the sixth-order k3 too (a "
        "flat port under water bends rays with strong high orders: scenarios/flatport_study.yaml)")] = False
    refine_distortion: Annotated[bool, about(
        "refine 'joints' also refines the lens's k1 k2 p1 p2 under the lab calibration's covariance (the lab's "
        "distortion is the largest error it leaves under water: docs/bounds.md)")] = True
    refine_k3: Annotated[bool, about(
        "with refine_distortion and the central camera model, the joint bundle also refines the lens's "
        "sixth-order k3, which the lab's Heikkila fit holds at zero, under a wide independent prior "
        "(bench.vision.joint_bundle.K3_PRIOR_SD) - with lab_k3 under the lab's own covariance of k1 k2 p1 p2 k3 "
        "and its cross-covariances: behind a flat port the best central camera needs one (docs/bounds.md); the "
        "bound carries it too. Off by default (docs/bounds.md)")] = False
    target_tolerance: Annotated[bool, about(
        "the lab calibrations' priors also carry what the rig's stated tolerances (target.yaml) leave in the "
        "intrinsics and the mount (bench.camera.target_tolerance; Monte Carlo of tolerance_draws draws)")] = True
    tolerance_draws: Annotated[int, Field(ge=10, le=1000)] = 48
    camera_model: Annotated[Literal["central", "refractive"], about(
        "the camera model the lab calibrates and the localisation uses: central (Heikkila, as the thesis) or "
        "refractive (the lens behind the housing's flat port, calibrated from the same rig views with the dataset's "
        "housing.yaml: bench.camera.refractive; needs a camera in water)")] = "central"
    guided: Annotated[bool, about(
        "refine 'joints' then searches the map again in both locate views at the refined poses and re-runs the joint "
        "bundle on the grown set (bench.vision.guided; not the thesis's): docs/integrity.md measures it")] = False
    loss: Annotated[Literal["none", "huber"], about(
        "the joint bundle's loss (refine 'joints'): least squares on the gated observations, or Huber's M-estimate "
        "(bench.vision.bundle.robust_weights): docs/bounds.md measures it")] = "none"
    map_points: Annotated[Literal["all", "located"], about(
        "the map points the joint bundle weighs (refine 'joints'): all of them, or only those both locate views "
        "matched; the others hold the survey views' joints and the shared lens and mount (docs/bounds.md measures "
        "it)")] = "all"
    ins_tilt: Annotated[Literal["fuse", "check"], about(
        "the vehicle's INS tilt (vehicle.ins): test 7 on the images' pose, then fused into the pose and its "
        "protection levels (fuse), or test 7 only (check); the bound takes the INS when fused (bench.vision.tilt)")] = \
        "fuse"
    keypoints: Annotated[Literal["sift", "aligned"], about(
        "the keypoints the localisation uses: SIFT's (the thesis's) or aligned - every keypoint matched to its "
        "region's reference keypoint moved onto the reference's image patch (bench.vision.patch_align; "
        "docs/integrity.md measures it)")] = "sift"
    twin_keypoints: Annotated[Literal["both", "once", "weighted"], about(
        "SIFT's twin keypoints (a second orientation at the same pixel, matched with nearly the same error in every "
        "view): both copies as the thesis's map keeps them (both), which counts such a point twice in the covariance; "
        "one point per detection observed wherever a copy was matched (once; bench.vision.insitu.MapConfig."
        "duplicate_px); or both copies with each view's shared keypoint weighed as what it is worth in the joint "
        "bundle, bench.vision.insitu.TWIN_WORTH measurements (weighted; docs/integrity.md measures them)")] = "both"
    covariance: Annotated[Literal["white", "field"], about(
        "refine joints: the pose's covariance of white pixel noise, or with each view's keypoint error field (to "
        "cubic order) measured on the joint bundle's residuals (bench.vision.field_covariance; docs/integrity.md "
        "measures it)")] = "white"

    @model_validator(mode="after")
    def _needs_joints(self):
        if self.locate == "pnp" and self.refine != "none":
            raise KeyProblem("locate", f"pnp refines its own pose (LM on its inliers): set pipeline.refine=none, got "
                                       f"refine {self.refine!r}")
        for key, on in (("guided", self.guided), ("loss", self.loss != "none"),
                        ("map_points", self.map_points != "all"), ("covariance", self.covariance != "white")):
            if on and self.refine != "joints":
                raise KeyProblem(key, f"used only by refine 'joints', got refine {self.refine!r}")
        return self


class Sources(Section):
    """Error sources, for the error budget: switching one off injects the truth explicitly (evaluator side), e.g.
    kinematics=perfect gives the pipeline the true errors and mount instead of its calibration."""

    kinematics: Literal[SOURCES["kinematics"]] = "calibrated"
    camera: Literal[SOURCES["camera"]] = "calibrated"
    encoders: Literal[SOURCES["encoders"]] = "real"
    features: Literal[SOURCES["features"]] = "sift"


class Bound(Section):
    """The Cramér-Rao bound of the base pose and a Monte Carlo of the ideal estimator (in_situ_bound); ml_trials > 0:
    also a Monte Carlo of refine 'joints' under exactly the bound's model (base_*_crb_mc_*; ~2 s a trial), the check
    that the estimator reaches the bound. keypoint_field: the keypoints' errors also move each view's keypoints
    together (a polynomial field per view of keypoint_field_order: 1 affine, 3 cubic; each view's modes independent,
    each degree's sd measured on the panel's true surfaces: keypoint_field_*); false: white."""

    enabled: bool = True
    mc_trials: NonNegInt = 30
    ml_trials: NonNegInt = 0
    keypoint_field: bool = True
    keypoint_field_order: Annotated[int, Field(ge=1, le=3)] = 3


class Outputs(Section):
    cache: bool = True
    rerun: bool = True


class Scenario(ScenarioBase):
    """An ``in_situ`` scenario file."""

    robot: str = "../models/ta40.yaml"
    truth: Truth = section(Truth)
    camera: Camera = section(Camera)
    encoders: Encoders = section(Encoders)
    lab: Lab = section(Lab)
    site: Site = section(Site)
    vehicle: Vehicle = section(Vehicle)
    survey: Survey = section(Survey)
    task: Task = section(Task)
    locate: Locate = section(Locate)
    pipeline: Pipeline = section(Pipeline)
    sources: Sources = section(Sources)
    bound: Bound = section(Bound)
    outputs: Outputs = section(Outputs)


# bench budget: the overrides that make each error source perfect (issue: perfect features, perfect optics model -
# the same camera model in simulator and pipeline -, perfect kinematics, perfect encoders)
BUDGET = {"features": {"sources.features": "perfect"}, "optics_model": {"sources.camera": "perfect"},
          "kinematics": {"sources.kinematics": "perfect"}, "encoders": {"sources.encoders": "perfect"}}
BUDGET_METRICS = ["base_pos_err_mm", "base_rot_err_deg", "valve_tool_err_mm"]
BUDGET_FIXED = {"outputs.rerun": False, "bound.enabled": False}
#: each budgeted metric's signed components (survey base frame; the valve's in the world frame): the budget pairs a
#: variant's error vector with the full run's, seed by seed (:func:`bench.scenario.budget.budget_from_rows`)
BUDGET_VECTORS = {m: tuple(f"{m.rsplit('_', 1)[0]}_{a}_{m.rsplit('_', 1)[1]}" for a in "xyz") for m in BUDGET_METRICS}

DEG = np.pi / 180
#: the IK seed of the rig views after the first
Q_HOME = np.deg2rad([28.0, 37.0, 49.0, 82.0, 29.0, 0.0])


def imaging(cfg):
    """The scenario's imaging profile (``camera.imaging``, ``camera.imaging_off``: :mod:`bench.sim.imaging`)."""
    return profile_from_config(cfg, "camera")


def site_optics(cfg):
    """The camera preset's optics (``camera.preset``) in the scenario's water (``site.water``).

    ``site.water: preset`` keeps the preset's own water (``coastal`` for ``underwater_in_water``, none in air);
    a name of :data:`bench.sim.medium.WATER_PRESETS` replaces it, which needs a camera in water (a port into the
    sea). Unknown names and a water for a camera in air are one-line errors naming the key."""
    from bench.sim.medium import WATER_PRESETS

    src, water = cfg["_file"], cfg["site"]["water"]
    try:
        base = optics_preset(cfg["camera"]["preset"])
    except ValueError as exc:
        raise ConfigError(src, "camera.preset", str(exc)) from None
    if water == "preset":
        return base
    if water not in WATER_PRESETS:
        raise ConfigError(src, "site.water", f"unknown water {water!r} (known: preset, "
                                             f"{', '.join(sorted(WATER_PRESETS))})")
    if base.port is None or base.port.n_water == base.port.n_air:
        raise ConfigError(src, "site.water", f"{water!r} needs a camera in water (camera.preset: underwater_in_water"
                                             f"), but camera.preset {cfg['camera']['preset']!r} is in air")
    return optics_preset(cfg["camera"]["preset"], overrides={"water": {"preset": water}})


def validate(cfg) -> None:
    """The checks the model cannot make, before anything is created (also run by ``bench sweep`` up front): the
    imaging profile, the optics in the site's water, the housing tolerance against the port, the tracker poses
    against the robot's identifiable errors, a camera in water where one is needed, the texture files."""
    src = cfg["_file"]
    imaging(cfg)
    port = site_optics(cfg).port
    in_water = port is not None and port.n_water != port.n_air
    if in_water:  # housing.yaml's d0 = the true one off by up to the tolerance
        d0_mm = port.axial_d0 * 1e3
        if cfg["camera"]["housing_tolerance_mm"] >= d0_mm:
            raise ConfigError(src, "camera.housing_tolerance_mm", f"must be below the port's lens-to-glass distance "
                                                                  f"({d0_mm:.1f} mm), got "
                                                                  f"{cfg['camera']['housing_tolerance_mm']}")
    # the lab calibration identifies the arm from the tracker points (3 equations each)
    n_params = len(closed_form_reduction(load_robot(Path(src).parent / cfg["robot"])).kept)
    n = cfg["lab"]["tracker_poses"]
    if 3 * n < n_params:
        raise ConfigError(src, "lab.tracker_poses", f"{n} poses give {3 * n} equations for {n_params} identifiable "
                                                    f"errors; need at least {-(-n_params // 3)}")
    for key, on in (("pipeline.camera_model", cfg["pipeline"]["camera_model"] == "refractive"),
                    ("lab.rig_in_air", cfg["lab"]["rig_in_air"])):
        if on and not in_water:
            raise ConfigError(src, key, f"needs a camera behind a port in water, but camera.preset "
                                        f"{cfg['camera']['preset']!r} is in air")
    if cfg["pipeline"]["refine_k3"]:  # asked for explicitly (off by default): a setting that cannot apply is refused
        for key, bad, why in (("pipeline.refine_distortion", not cfg["pipeline"]["refine_distortion"],
                               "must be true (k3 is refined with k1 k2 p1 p2)"),
                              ("pipeline.camera_model", cfg["pipeline"]["camera_model"] != "central",
                               "must be central (the refractive camera's lens is behind the port)")):
            if bad:
                raise ConfigError(src, key, f"{why} with pipeline.refine_k3")
    if cfg["pipeline"]["locate"] == "pnp" and cfg["bound"]["ml_trials"] > 0:
        raise ConfigError(src, "bound.ml_trials", "the Monte Carlo of refine 'joints' (two locate views); not "
                                                  "with pipeline.locate=pnp (its bound's own Monte Carlo is "
                                                  "bound.mc_trials)")
    texture_paths(cfg, "site.textures")
    regions = cfg["site"]["regions_m"]
    for i, (x, y) in enumerate(regions):
        if abs(x) > cfg["site"]["panel_width_m"] / 2 or abs(y) > cfg["site"]["panel_height_m"] / 2:
            raise ConfigError(src, f"site.regions_m[{i}]", f"[{x}, {y}] m lies off the {cfg['site']['panel_width_m']}"
                                                           f" x {cfg['site']['panel_height_m']} m panel")
    if len(regions) > 1:  # several regions are solved together by the joint bundle; the bound takes one
        for key, bad, why in (("pipeline.refine", cfg["pipeline"]["refine"] != "joints", "must be joints"),
                              ("pipeline.locate", cfg["pipeline"]["locate"] != "two_view", "must be two_view"),
                              ("bound.enabled", cfg["bound"]["enabled"], "must be false (the bound takes one region)"),
                              ("sources.features", cfg["sources"]["features"] != "sift",
                               "must be sift (perfect features take one region)")):
            if bad:
                raise ConfigError(src, key, f"{why} with {len(regions)} site.regions_m")


# ------------------------------------------------------------------------------------------------ truth


def _truth(cfg, robot, rng):
    t = cfg["truth"]
    eps = random_errors(rng, trans=t["error_trans_mm"] * 1e-3, rot=t["error_rot_deg"] * DEG)
    mount = homogeneous(rot_z(t["mount_roll_deg"] * DEG), np.array(t["mount_mm"], float) * 1e-3)
    b = np.array(t["mount_bias_deg"], float) * DEG  # thesis theta_x0, theta_y0, theta_z0 (Eq. 197, as labelled)
    bias = homogeneous(rot_y(b[1]) @ rot_x(b[0]) @ rot_z(b[2]), np.array(t["mount_bias_mm"], float) * 1e-3)
    optics = site_optics(cfg)  # camera.preset in site.water
    nominal_cam = load_preset(optics.nominal_camera)  # the specification the pipeline is given
    lens = load_preset(optics.lens_camera)  # the lens inside the housing (= the whole camera in air)
    # the true lens: the nominal one perturbed (its distortion the real webcam's measured one under realistic imaging)
    true_cam = draw_true_lens(lens, rng, imaging(cfg), t["focal_error_pct"], t["principal_error_px"])
    return eps, mount, mount @ bias, nominal_cam, true_cam, optics


def _random_motion(rng, trans_m, rot_deg, vertical=0.3):
    """A ROV parking perturbation: yaw up to ``rot_deg``, roll/pitch a fifth of it, translation mostly horizontal."""
    R = rot_z(rng.uniform(-1, 1) * rot_deg * DEG) @ rot_x(rng.uniform(-1, 1) * rot_deg * DEG / 5) @ \
        rot_y(rng.uniform(-1, 1) * rot_deg * DEG / 5)
    t = rng.uniform(-1, 1, 3) * trans_m * np.array([1.0, 1.0, vertical])
    return homogeneous(R, t)


def _effective_camera(port) -> np.ndarray:
    """``T_lens_effective`` (4, 4): the centre of the central camera equivalent to lens + flat port (identity
    without a port).

    Behind a flat port the water rays converge, paraxially, on a virtual centre on the axis at
    ``z_v = (d0 + t) - (d0 + t n_air / n_glass) n_water / n_air`` (-5.6 mm for the 20 mm / 12 mm housing in sea
    water): the camera centre a calibration in water finds, and what the evaluator scores the calibrated mount's
    position against. The port's tilt also turns the principal ray (by ~``tilt (1 - n_air / n_water)``, 0.28 deg
    here), but a small turn of the axis and a shift of the principal point are nearly the same to a calibration, so
    the calibrated intrinsics and the mount rotation share it: no rotation is put into the effective camera, and
    ``mount_rot_err_deg`` in water contains that share (0.3-0.5 deg measured)."""
    if port is None:
        return np.eye(4)
    z_v = (port.d0 + port.t) - (port.d0 + port.t * port.n_air / port.n_glass) * port.n_water / port.n_air
    return homogeneous(np.eye(3), [0.0, 0.0, z_v])


def _paraxial_K(K, mag) -> np.ndarray:
    """The intrinsics (3, 3) of the central camera paraxially equivalent to lens ``K`` behind a flat port of
    magnification ``mag`` (n_water / n_air): the focal lengths (and skew) scale, the principal point - where the
    optical axis meets the image, unmoved by a port normal to it - does not (``diag(mag, mag, 1) @ K`` would move it
    to ``mag`` times its distance from the image corner: ~100 px)."""
    K = np.array(K, dtype=float)
    K[:2, :2] *= mag
    return K


def _survey_offsets(cfg, nominal_cam) -> np.ndarray:
    """Eye offsets (m) of the surrounding views in the reference camera's image plane, (k, 3).

    ``survey.offsets_mm`` if given; otherwise ``survey.directions`` offsets on a circle whose radius is the
    intraocular distance of Eq. 199 for ``survey.depth_resolution_mm`` at the panel's range, 1 px disparity error
    and the nominal focal length (the only one known before calibration).
    """
    rows = cfg["survey"]["offsets_mm"]
    if rows:
        return np.c_[np.array(rows, dtype=float) * 1e-3, np.zeros(len(rows))]
    radius = float(required_baseline(cfg["site"]["standoff_m"], nominal_cam.fx,
                                     cfg["survey"]["depth_resolution_mm"] * 1e-3))  # Eq. 199
    if cfg["survey"]["radius_limit_mm"] > 0:  # the arm sweeps what it can: a coarser depth resolution (Eq. 199)
        radius = min(radius, cfg["survey"]["radius_limit_mm"] * 1e-3)
    a = np.linspace(0, 2 * np.pi, cfg["survey"]["directions"], endpoint=False)
    return np.c_[radius * np.cos(a), radius * np.sin(a), np.zeros(len(a))]


def _valve_targets(panel, T_world_panel, cfg) -> list:
    """Candidate valves ``(name, centre_world, axis_world)``, nearest the panel centre first (or the one named)."""
    valves = panel.features["valves"]
    choice = cfg["task"]["valve"]
    if choice != "nearest" and choice not in valves:
        raise ConfigError(cfg["_file"], "task.valve", f"unknown valve {choice!r} (panel has {', '.join(valves)}; "
                                                      "or 'nearest')")
    names = [choice] if choice != "nearest" else \
        sorted(valves, key=lambda k: np.linalg.norm(np.asarray(valves[k]["centre"])[:2]))
    return [(k, transform_points(T_world_panel, valves[k]["centre"]), T_world_panel[:3, :3] @ valves[k]["axis"])
            for k in names]


@memoized
def _teach(robot, eps, T_wb1, T_wb2, valves, q_seed, rolls: int = 12):
    """The operator puts the tool on a valve handle at parking 1 (true arm): tool tip O6 on the handle centre, tool
    axis along the valve stem into the panel. Returns the first valve (in ``valves`` order) reachable so at parking 1
    and, tip position only, at parking 2; ``None`` if there is none."""
    for name, p_w, axis_w in valves:
        z = -np.asarray(axis_w) / np.linalg.norm(axis_w)
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R0 = np.column_stack([x, np.cross(z, x), z])
        for roll in np.linspace(0, 2 * np.pi, rolls, endpoint=False):
            T_w_ee = homogeneous(R0 @ rot_z(roll), p_w)
            sol = compensated_ik(robot, eps, invert(T_wb1) @ T_w_ee, q_seed=q_seed)
            if not sol.success:
                continue
            q_teach = sol.solutions[0]
            again = compensated_ik(robot, eps, invert(T_wb2) @ T_w_ee, q_seed=q_teach, position_only=True)
            if again.success:
                return {"valve": name, "centre_world": p_w, "T_world_ee": T_w_ee, "q_true": q_teach}
            break  # parking 2 reaches this handle with no roll if it fails for a reachable one
    return None


def _why_unreachable(robot, eps, cfg, looks, valves, mount) -> str:
    """The reason, in numbers, that no parking reached the views (``looks``: ``(eye, aim point)`` of each, world)
    and valve: the first view the nominal parking (no ROV offset) cannot reach, with the wrist's reach
    (:func:`bench.sim.views.reach_diagnosis`); else the valve's distance against the tool's reach; else the parking
    perturbation."""
    from bench.sim.views import reach_diagnosis, wrist_reach

    site = cfg["site"]
    placed = f"site.eye_m {site['eye_m']}" if site["placement"] == "eye" else \
        f"site.panel_centre_m {site['panel_centre_m']}"
    where = f"site.standoff_m {site['standoff_m']:g} m, {placed}"
    q_seed = None
    for eye, aim in looks:
        sol = _plan(robot, np.eye(4), eye, aim, mount, q_seed)
        if not sol.success:
            d = reach_diagnosis(robot, eye, aim, mount)
            return f"{where}: even at the nominal parking, {d['message']}"
        q_seed = sol.q if q_seed is None else q_seed
    if cfg["task"]["teach"] and valves:
        _, r_max = wrist_reach(robot)
        tool = r_max + float(np.linalg.norm(robot.p_ee + np.array([0.0, 0.0, robot.d[5]])))
        def from_shoulder(p):  # the shoulder (joint-2 axis) turns with joint 1 at a1 from the base's z axis
            az = np.arctan2(p[1], p[0])
            return float(np.linalg.norm(p - robot.a[0] * np.array([np.cos(az), np.sin(az), 0.0])))

        dist = min(from_shoulder(v[1]) for v in valves)
        if dist > tool - 0.05:
            return (f"{where}: at the nominal parking the nearest valve is {dist:.2f} m from the shoulder, the tool "
                    f"tip reaches at most "
                    f"{tool:.2f} m (task.teach: false localises without the task)")
        return (f"{where}: the views are reachable at the nominal parking, but no drawn parking also reaches a valve "
                f"at both parkings (valve {dist:.2f} m from the shoulder, tool reach {tool:.2f} m): reduce "
                "site.base_offset_m / base_rot_deg / locate.motion_m, or task.teach: false")
    return (f"{where}: the views are reachable at the nominal parking but not at {site['parking_attempts']} drawn "
            f"parkings (+-{site['base_offset_m']:g} m, +-{site['base_rot_deg']:g} deg, then "
            f"+-{cfg['locate']['motion_m']:g} m, +-{cfg['locate']['motion_deg']:g} deg): reduce them or raise "
            "site.parking_attempts")


def _rig_views(robot, rig_centre, distance, n, prefix, mount_nominal, role="rig"):
    """``(views, unreachable)``: ``n`` views of the rig from ``distance`` (m) in directions spread over +-25 deg
    azimuth and +-12 deg elevation (rotation diversity for AX = XB), base at the world origin; the requested views the
    arm cannot take are listed (reported, not silently dropped)."""
    az = np.linspace(-25, 25, n) * DEG
    el = 12 * DEG * np.sin(np.linspace(0, 2 * np.pi, n, endpoint=False))
    views, unreachable = [], []
    for k in range(n):
        direction = np.array([np.cos(el[k]) * np.cos(az[k]), np.cos(el[k]) * np.sin(az[k]), np.sin(el[k])])
        sol = _plan(robot, np.eye(4), rig_centre - distance * direction, rig_centre, mount_nominal,
                    Q_HOME if k else None)
        if not sol.success:
            unreachable.append(f"{prefix}{k:02d} ({sol.message})")
            continue
        views.append((f"{prefix}{k:02d}", role, np.eye(4), sol.q))
    return views, unreachable


def locate_offsets(baseline_m: float, direction_deg: float = 0.0) -> np.ndarray:
    """The two locate eyes ``(2, 3)`` in the reference view's look frame (OpenCV: x right, y down; m): ``baseline_m``
    apart about its centre, along the image's x turned by ``direction_deg`` towards image-up (``-y``)."""
    a = np.deg2rad(direction_deg)
    half = 0.5 * baseline_m * np.array([np.cos(a), -np.sin(a), 0.0])
    return np.array([-half, half])


@memoized
def _plan(robot, T_world_base, eye_w, target_w, mount, q_seed):
    from bench.sim.views import look_at_configuration

    T_base_world = invert(T_world_base)
    return look_at_configuration(robot, transform_points(T_base_world, eye_w), transform_points(T_base_world, target_w),
                                 mount, q_seed=q_seed, n_starts=6)


# ------------------------------------------------------------------------------------------------ simulation


def _site_panel(cfg, rng):
    """The site's manifold panel, drawn from ``rng`` right after :func:`_truth` (the render's order)."""
    from bench.sim.scenes.panel import manifold_panel

    with naming_the_key(cfg, "site.textures"):
        return manifold_panel(rng, cfg["site"]["panel_width_m"], cfg["site"]["panel_height_m"], name="panel",
                              texture_overrides=texture_paths(cfg, "site.textures"))


def replay_panel(cfg):
    """EVALUATOR SIDE: the panel a render of ``cfg`` (its seed) placed at ``truth.yaml``'s ``T_world_panel``, drawn
    again from the seed (the render's draws, in the render's order), for ray casting onto its true surfaces
    (:class:`bench.scenario.scene_points.SceneRays`)."""
    rng = np.random.default_rng(cfg["seed"])
    _truth(cfg, load_robot(Path(cfg["_file"]).parent / cfg["robot"]), rng)
    return _site_panel(cfg, rng)


def render(cfg, out_dataset, verbose=True, cache_dir=None) -> dict:
    """Simulate the campaign and write the dataset (with ``truth/``); returns the simulator's metrics."""
    from bench.sim.campaign import ArmScene
    from bench.sim.checks import distortion_roundtrip, kinematics_check, marker_check
    from bench.sim.encoders import EncoderModel
    from bench.sim.scenes.base import place
    from bench.sim.scenes.rig import calibration_rig
    from bench.sim.views import look_at

    t0 = time.perf_counter()
    rng = np.random.default_rng(cfg["seed"])
    robot = load_robot(Path(cfg["_file"]).parent / cfg["robot"])
    eps, mount_nominal, mount_true, nominal_cam, true_cam, optics = _truth(cfg, robot, rng)
    port = optics.port
    # the paraxial focal length of lens + flat port is n_water / n_air times the lens's (no port: the lens's)
    mag = port.n_water / port.n_air if port is not None else 1.0
    # sources.camera = perfect renders the same images: it gives the pipeline the true optics model (_oracle_files)
    perfect = cfg["sources"]["encoders"] == "perfect"
    enc = EncoderModel(0.0 if perfect else cfg["encoders"]["noise_deg"] * DEG,
                       0.0 if perfect else cfg["encoders"]["resolution_deg"] * DEG)
    # every random source draws from a stream of its own, so that switching one off (bench budget) leaves the
    # others' draws - the truth, the parking, the tracker campaign - exactly as they were: the variants are paired
    rng_enc = np.random.default_rng([cfg["seed"], 21])
    rng_enc_extra = np.random.default_rng([cfg["seed"], 23])
    site = cfg["site"]

    # --- site geometry: the panel faces the arm (normal -x of the world), within reach of the nominal base ----------
    if site["placement"] == "eye":  # the reference eye where the arm reaches it, the panel standoff_m ahead
        eye_ref = np.array(cfg["site"]["eye_m"], float)
        centre = eye_ref + np.array([site["standoff_m"], 0.0, 0.0])
    else:
        centre = np.array(cfg["site"]["panel_centre_m"], float)  # world = the nominal base frame, before the ROV parks
        eye_ref = centre - np.array([site["standoff_m"], 0.0, 0.0])
    R_wp = np.column_stack([[0, -1, 0], [0, 0, 1], [-1, 0, 0]]).astype(float)  # panel x, y (up), z (out) in world
    T_world_panel = homogeneous(R_wp, centre)
    panel = _site_panel(cfg, rng)
    # the lab rig: fold line vertical, both boards facing the arm, in front of the nominal base
    rig_origin = np.array(cfg["lab"]["eye_base_m"], float) + np.array([cfg["lab"]["rig_distance_m"], 0.0, -0.12])
    T_world_rig = homogeneous(rot_z(3 * np.pi / 4), rig_origin)  # both boards face the arm (-x of the world)
    rig = calibration_rig(name="rig", errors=rig_errors(imaging(cfg), cfg["seed"]))
    rig_centre = transform_points(T_world_rig, rig.features["corners"]).mean(axis=0)

    # --- lab: rig views from several directions (rotation diversity for AX = XB), base at the world origin -----------
    n_rig = cfg["lab"]["rig_views"]  # views: (name, role, T_world_base, q_true)
    views, unreachable = _rig_views(robot, rig_centre, cfg["lab"]["rig_distance_m"], n_rig, "rig", mount_nominal)

    # --- site: parking 1 (survey, task taught) and parking 2 (locate, task executed) ---------------------------------
    T_ref_look = look_at(eye_ref, centre)
    survey_eyes = [eye_ref] + list(transform_points(T_ref_look, _survey_offsets(cfg, nominal_cam)))
    base_l = cfg["locate"]["baseline_mm"] * 1e-3
    locate_eyes = list(transform_points(T_ref_look, locate_offsets(base_l, cfg["locate"]["baseline_direction_deg"])))
    # regions after the first: the same pattern of eyes moved in the panel's plane to aim at another part of it
    regions = [(R_wp @ np.array([x, y, 0.0]), f"r{k}") for k, (x, y) in enumerate(site["regions_m"])]
    shift0 = regions[0][0]
    survey_eyes, locate_eyes, centre_aim = ([e + shift0 for e in survey_eyes], [e + shift0 for e in locate_eyes],
                                            centre + shift0)
    valves = _valve_targets(panel, T_world_panel, cfg)
    ok, parkings = False, 0
    while not ok and parkings < site["parking_attempts"]:
        parkings += 1
        T_wb1 = _random_motion(rng, site["base_offset_m"], site["base_rot_deg"])
        T_wb2 = T_wb1 @ _random_motion(rng, cfg["locate"]["motion_m"], cfg["locate"]["motion_deg"])
        site_views, ok, q_seed = [], True, None
        for i, eye in enumerate(survey_eyes):
            sol = _plan(robot, T_wb1, eye, centre_aim, mount_nominal, q_seed)
            if not sol.success:
                ok = False
                break
            site_views.append(("ref" if i == 0 else f"survey{i:02d}", "reference" if i == 0 else "surround", T_wb1,
                               sol.q))
            q_seed = sol.q if i == 0 else site_views[0][3]
        for i, eye in enumerate(locate_eyes if ok else []):
            sol = _plan(robot, T_wb2, eye, centre_aim, mount_nominal, site_views[0][3])
            if not sol.success:
                ok = False
                break
            site_views.append((f"locate{i}", "locate", T_wb2, sol.q))
        region_views = []  # the other regions' views: rendered last (no draw of the first region's views moves)
        for shift, name in regions[1:] if ok else []:
            d = shift - shift0
            move = d if site["region_views"] == "shifted" else np.zeros(3)  # aimed: the first region's eyes
            plan = ([(f"{name}_ref" if i == 0 else f"{name}_survey{i:02d}", "reference" if i == 0 else "surround",
                      T_wb1, e + move) for i, e in enumerate(survey_eyes)]
                    + [(f"{name}_locate{i}", "locate", T_wb2, e + move) for i, e in enumerate(locate_eyes)])
            for view, role, T_wb, eye in plan:
                sol = _plan(robot, T_wb, eye, centre_aim + d, mount_nominal, site_views[0][3])
                if not sol.success:
                    ok = False
                    break
                region_views.append((view, role, T_wb, sol.q))
            if not ok:
                break
        task = _teach(robot, eps, T_wb1, T_wb2, valves, site_views[0][3]) if ok and cfg["task"]["teach"] else None
        if ok and cfg["task"]["teach"] and task is None:
            ok = False  # no valve within reach at both parkings: the pilot parks again
    if not ok:
        shifted = site["region_views"] == "shifted"
        looks = [(e + (shift - shift0 if shifted else 0.0), centre + shift) for shift, _ in regions
                 for e in survey_eyes + locate_eyes]
        raise ConfigError(cfg["_file"], "site", f"no reachable set of views (and valve) in {parkings} random parkings: "
                                                + _why_unreachable(robot, eps, cfg, looks, valves, mount_nominal))
    views += site_views
    n_paired = len(views)  # the views every variant renders: the ones after read their own encoder stream
    # rig_in_air: before the tank is flooded, closer by the port's magnification so that the rig covers the image as
    # in water (rendered last: no draw moves); then the extra distances
    more = ([(cfg["lab"]["rig_distance_m"] / mag, "rigair", "rig_air")] if cfg["lab"]["rig_in_air"] else []) + [
        (float(d), f"rig{i + 1}d", "rig") for i, d in enumerate(cfg["lab"]["rig_extra_distances_m"])]
    for d, prefix, role in more:
        extra, extra_unreachable = _rig_views(robot, rig_centre, d, n_rig, prefix, mount_nominal, role=role)
        views += extra
        unreachable += extra_unreachable
    n_requested = n_rig * (1 + len(more))
    views += region_views
    region_of = {v[0]: "r0" if len(regions) > 1 else "" for v in site_views}
    region_of.update({v[0]: v[0].split("_")[0] for v in region_views})
    if unreachable and verbose:  # the lab's rig views in water, in air and at the extra distances
        print(f"warning: {len(unreachable)} of {n_requested} requested rig views not reachable, not rendered (truth/"
              f"sim_checks.json: rig_views_unreachable): {'; '.join(unreachable)}", file=sys.stderr)
    t_plan = time.perf_counter() - t0

    # --- render ----------------------------------------------------------------------------------------------------
    objects = {"rig": [place(rig, T_world_rig, "rig_lab")]}  # the lab
    objects["rig_air"] = objects["rig"]
    # the housing in air: the same port with air outside, no water, no lamp (the lab is lit)
    air = optics_preset(cfg["camera"]["preset"], overrides={"port": {"n_water": port.n_air}, "water": None,
                                                            "light": None}) if cfg["lab"]["rig_in_air"] else None
    objects.update({r: [place(panel, T_world_panel, "panel_site")] for r in ("reference", "surround", "locate")})
    scenes = {}
    images, readings = {}, {}
    ss = cfg["camera"]["supersample"]
    if verbose:
        n_site = len(site_views) + len(region_views)
        print(f"rendering {len(views)} views ({len(views) - n_site} rig, {n_site} site) ...",
              file=sys.stderr)
    for n, (name, role, T_wb, q) in enumerate(views):
        key = ("rig" if role == "rig" else role if role == "rig_air" else "site",) + tuple(np.round(T_wb, 12).ravel())
        if key not in scenes:
            chain, port_r = (air.chain, air.port) if role == "rig_air" else (optics.chain, port)
            scenes[key] = ArmScene(robot, eps, T_wb, mount_true, true_cam, objects[role], ss, chain, cache_dir,
                                   T_link5_mount=mount_nominal, port=port_r, imaging=imaging(cfg))
        images[name] = scenes[key].render(q, seed=cfg["seed"] * 1000 + n)
        # the air views read their encoders from a stream of their own: the other readings stay paired
        readings[name] = enc.read(q, rng_enc if n < n_paired else rng_enc_extra)
        if verbose:
            print(f"\r  {n + 1}/{len(views)}", end="", file=sys.stderr)
    if verbose:
        print(file=sys.stderr)
    render_s = [s for sc in scenes.values() for s in sc.render_s]
    for sc in scenes.values():
        sc.close()

    # --- tracker campaign (lab, base at the origin; the tracker frame is the base frame found from the arcs) -------
    rng_tr = np.random.default_rng([cfg["seed"], 22])
    q_tr = robot.random_configurations(rng_tr, cfg["lab"]["tracker_poses"])
    p_tr = ee_position(robot, q_tr, eps) + rng_tr.normal(0, cfg["lab"]["tracker_sigma_mm"] * 1e-3, (len(q_tr), 3))
    q_tr_read = enc.read(q_tr, rng_enc)
    q_task_read = enc.read(task["q_true"], rng_enc) if task is not None else None

    # --- write the dataset --------------------------------------------------------------------------------------------
    out_dataset = Path(out_dataset)
    with DatasetWriter(out_dataset, kind="in_situ", name=cfg["name"], overwrite=True,
                       command="sim render", identity=cfg["name"],
                       created_by=f"bench sim render {Path(cfg['_file']).name} (seed {cfg['seed']})") as w:
        for name, role, _, _ in views:
            w.add_view(name, images[name], q=readings[name], role=role, region=region_of.get(name, ""))
        if task is not None:
            w.add_view(f"task_{task['valve']}", None, q=q_task_read, role="task",
                       notes="tool tip on the valve handle, taught at the survey parking")
        w.write_tracker([f"p{i:03d}" for i in range(len(q_tr))], p_tr, q_tr_read)
        w.write_text("camera.yaml", camera_yaml_text(nominal_cam))
        if port is not None and port.n_water != port.n_air:  # the housing's datasheet: its lens-to-glass distance
            tol = cfg["camera"]["housing_tolerance_mm"]  # off by a draw within its tolerance (own stream: the
            off = np.random.default_rng([cfg["seed"], 271]).uniform(-1, 1) * tol * 1e-3  # renders stay the same)
            nominal = port.centred(off, keep_tilt=False)
            w.write_text("housing.yaml", housing_yaml_text(nominal, tol))
        shutil.copyfile(Path(cfg["_file"]).parent / cfg["robot"], w.path("robot.yaml"))
        w.write_text("target.yaml", rig_target_yaml(imaging(cfg)))  # the rig's stated print tolerances
        # the encoders' datasheet (the configured specification, not the draws): refine 'joints' weighs the readings
        w.write_text("encoders.yaml", f"noise_deg: {cfg['encoders']['noise_deg']}\n"
                                      f"resolution_deg: {cfg['encoders']['resolution_deg']}\n")
        veh = cfg["vehicle"]
        if veh["ins"]:  # the INS at the two parkings (a stream of its own: the renders and readings do not move)
            w.write_text(VEHICLE_FILE, vehicle_yaml_text(T_wb1, T_wb2, veh["tilt_sigma_deg"],
                                                         veh["alignment_sigma_deg"],
                                                         np.random.default_rng([cfg["seed"], 313])))
        truth = {
            "units": "SI (m, rad)",
            "errors": eps.tolist(),
            "T_link5_cam": mount_true.tolist(),
            # the central camera a calibration in water finds (see _effective_camera): the mount of the lens moved
            # to the port's paraxial virtual centre and turned onto the principal ray as it leaves the glass
            "T_link5_cam_effective": (mount_true @ _effective_camera(port)).tolist(),
            "T_link5_cam_nominal": mount_nominal.tolist(),
            "camera_K": true_cam.K.tolist(), "camera_dist": true_cam.dist.tolist(),
            "image_size": [int(true_cam.width), int(true_cam.height)],
            "camera_K_effective": _paraxial_K(true_cam.K, mag).tolist(),
            "T_world_rig": T_world_rig.tolist(), "T_world_panel": T_world_panel.tolist(),
            "views": {name: {"role": role, "T_world_base": T_wb.tolist(), "q_true": q.tolist()}
                      for name, role, T_wb, q in views},
            "T_world_base_survey": T_wb1.tolist(), "T_world_base_locate": T_wb2.tolist(),
            "valves_world": {k: {"centre": transform_points(T_world_panel, v["centre"]).tolist(),
                                 "axis": (R_wp @ np.asarray(v["axis"])).tolist()}
                             for k, v in panel.features["valves"].items()},
            "panel_corners_world": transform_points(T_world_panel, panel.features["corners"]).tolist(),
            "tracker_q_true": q_tr.tolist(),
            "task": None if task is None else {"view": f"task_{task['valve']}", "valve": task["valve"],
                                               "centre_world": task["centre_world"].tolist(),
                                               "T_world_ee": task["T_world_ee"].tolist(),
                                               "q_true": task["q_true"].tolist()},
            "encoders": {"noise_std_rad": enc.noise_std_rad, "resolution_rad": enc.resolution_rad},
            "water": None if optics.chain.medium is None else optics.chain.medium.name,
            "port": None if port is None else {"d0": port.d0, "t": port.t, "n_air": port.n_air,
                                               "n_glass": port.n_glass, "n_water": port.n_water,
                                               "tilt": port.tilt.tolist(), "decentre": port.decentre.tolist()},
        }
        w.write_text("truth/truth.yaml", yaml.safe_dump(truth, sort_keys=False))
        checks = kinematics_check(robot, eps, np.array([v[3] for v in views]))
        # the camera-convention self-check renders its markers at >= 2x: point-sampled at 1x, a marker's centroid
        # through Table 9's distortion is off by 0.13 px from aliasing alone, which says nothing about the convention
        checks.update(marker_check(true_cam, max(ss, 2)))
        checks["distortion_roundtrip_max_px"] = distortion_roundtrip(true_cam)
        if render_s:  # all views from the cache: no render was timed
            checks["render_fps"] = float(1.0 / np.median(render_s))
        from bench.vision.features import detect_sift

        counts = [len(detect_sift(images[n], channel_order="rgb")) for n, role, _, _ in views
                  if role in ("reference", "surround")]
        checks["panel_sift_keypoints"] = float(np.median(counts))
        checks["views_rendered"] = float(len(render_s))
        checks["rig_views_unreachable"] = float(len(unreachable))
        checks["plan_s"] = t_plan
        checks["parking_attempts"] = float(parkings)
        w.write_text("truth/sim_checks.json", json.dumps(checks, indent=2) + "\n")
    if verbose:
        print(f"wrote {out_dataset} ({len(views)} views, {len(q_tr)} tracker points)")
    return checks


# ------------------------------------------------------------------------------------------------ evaluation


def _oracle_files(cfg, ds, robot, out_dir, lab):
    """Camera, robot and calibration-priors files for the localisation: the pipeline's calibration, or - for an error
    source switched off (``sources``) - the truth, written explicitly by the evaluator into ``out_dir/oracle``.

    ``camera: perfect`` gives the true optics model on the same images: the lens itself in air, behind a flat port
    the best central camera for the scene (:func:`~bench.scenario.in_situ_bound.best_central_camera` over the panel's
    depths in the site views: what no central model removes stays, the model floor) under the lab calibration's own
    priors, so that the estimator is the real run's (refine 'joints' refines it in situ as it refines the lab's
    camera). Held fixed, the variant would also switch off that refinement, which under water compensates part of
    the floor (measured, every source perfect: 0.345 mm RMS held, 0.260 mm refined, 20 seeds), and the budget's
    paired displacements would not add up (closure 1.29 against 1.04; docs/bounds.md);
    its mount the true one with the true arm, else the one AX = XB finds on
    the calibrated arm from the rig views' true camera poses (the true mount does not go with the identified arm:
    the tracker sees positions only, the mount absorbs the wrist's orientation errors - measured 1.29 mm against
    0.07 mm in air). ``kinematics: perfect`` gives the true arm errors; with the
    *calibrated* camera the mount AX = XB finds from the same rig views with the true arm - the calibrated intrinsics
    and mount share the port's tilt and the camera's centre between them, so the true mount would not fit that
    camera (measured: the base error grew 1.5x with it). Returns ``(camera_path, robot_path, priors_path)``."""
    cal = Path(out_dir) / "calibrated"
    camera_path, robot_path, priors_path = cal / "camera.yaml", cal / "robot.yaml", cal / "calibration_priors.yaml"
    if cfg["sources"]["kinematics"] == "calibrated" and cfg["sources"]["camera"] == "calibrated":
        return camera_path, robot_path, priors_path
    truth = yaml.safe_load((ds.root / "truth" / "truth.yaml").read_text())
    oracle = Path(out_dir) / "oracle"
    oracle.mkdir(parents=True, exist_ok=True)
    eps_true = np.array(truth["errors"])
    eps, mount, notes = lab["eps"], lab["mount"].T_mount_cam, "ORACLE:"
    if cfg["sources"]["kinematics"] == "perfect":
        eps, notes = eps_true, "ORACLE: the true errors;"
        if cfg["sources"]["camera"] != "perfect":
            T_base_l5 = np.stack([link5_frame(robot, q, eps_true) for q in lab["rig_q"]])
            he = hand_eye_axxb(T_base_l5, lab["T_cam_target"])
            if not he.success:
                raise ConfigError(ds.root, "rig views", f"mount calibration on the true arm failed: {he.message}")
            mount, notes = he.T_mount_cam, notes + " mount by AX = XB on the true arm"
    if cfg["sources"]["camera"] == "perfect":
        from bench.scenario.in_situ_bound import best_central_camera

        lens, port, _ = _true_optics(truth)
        poses = _true_camera_poses(robot, truth)
        corners = np.array(truth["panel_corners_world"])
        z = np.concatenate([transform_points(invert(poses[n]), corners)[:, 2] for n, v in truth["views"].items()
                            if v["role"] in ("reference", "surround", "locate")])
        if lab.get("refractive") is not None:  # the true lens behind the true port (its decentre is in d0)
            from bench.camera.refractive import RefractiveCamera

            T_lens_c = np.eye(4)
            camera_path = write_camera_yaml(oracle / "camera.yaml", RefractiveCamera(
                lens, port.centred(), lab["refractive"].camera.working_range_m, name="ORACLE: true lens and port"))
        else:
            central, T_lens_c = best_central_camera(lens, port, (0.8 * float(z.min()), 1.2 * float(z.max())),
                                                    profile=imaging(cfg))
            cam = read_camera_yaml(camera_path)
            camera_path = write_camera_yaml(oracle / "camera.yaml", cam.replace(K=central.K, dist=central.dist,
                                                                                name="ORACLE: true central camera"))
        if cfg["sources"]["kinematics"] == "perfect":
            mount, notes = np.array(truth["T_link5_cam"]) @ T_lens_c, notes + " the true camera and mount"
        else:  # the mount that goes with the calibrated arm: AX = XB on the rig views' true camera poses
            rig = [n for n, v in truth["views"].items() if v["role"] == "rig"]
            T_cam_target = np.stack([invert(poses[n] @ T_lens_c) @ np.array(truth["T_world_rig"]) for n in rig])
            he = hand_eye_axxb(np.stack([link5_frame(robot, ds.view(n).q, eps) for n in rig]), T_cam_target)
            if not he.success:
                raise ConfigError(ds.root, "rig views", f"mount calibration with the true camera failed: {he.message}")
            mount, notes = he.T_mount_cam, notes + " the true camera; mount by AX = XB on its true rig poses"
    robot_path = write_calibrated_robot(oracle / "robot.yaml", ds.robot_path, robot, eps, mount, notes=notes)
    return camera_path, robot_path, priors_path


def _true_optics(truth):
    """The true lens (CameraModel), port (FlatPort or None) and the central camera equivalent to both."""
    w, h = truth["image_size"]
    lens = CameraModel(int(w), int(h), np.array(truth["camera_K"]), np.array(truth["camera_dist"]), "true lens")
    port = None if truth.get("port") is None else FlatPort(**{k: np.array(v) if isinstance(v, list) else v
                                                             for k, v in truth["port"].items()})
    central = lens.replace(K=np.array(truth["camera_K_effective"]), name="true central camera")
    return lens, port, central


def _true_camera_poses(robot, truth) -> dict:
    eps, mount = np.array(truth["errors"]), np.array(truth["T_link5_cam"])
    return {n: np.array(v["T_world_base"]) @ link5_frame(robot, np.array(v["q_true"]), eps) @ mount
            for n, v in truth["views"].items()}


def _perfect_features(cfg, robot, truth, details, res):
    """``features_fn`` for ``sources.features = perfect``, paired with the real run: the same points in the same
    views - the real run's map points (its site frame taken as the true survey base frame) in the views that
    observed them (:func:`~bench.scenario.in_situ_bound.observation_pattern`: the reference, the surrounding views
    that contributed, the locate views where the final solve used them), projected exactly through the true optics
    with exact correspondences."""
    from bench.scenario.in_situ_bound import ideal_features, observation_pattern, true_projector

    lens, port, _ = _true_optics(truth)
    project = true_projector(lens, port, imaging(cfg))
    kmap, names = details["map"], list(details["observations"])
    used = res.used[0] if res.success and res.used is not None else np.arange(len(kmap))
    vis = observation_pattern(kmap, len(names), used)
    X = transform_points(np.array(truth["T_world_base_survey"]) @ kmap.T_world_ref, kmap.p_ref)
    rows = {n: np.where(vis[k][:, None], X, np.nan) for k, n in enumerate(names)}
    poses = _true_camera_poses(robot, truth)
    return lambda view: ideal_features(rows[view.name], poses[view.name], project, lens.size)


def _bound(cfg, robot, truth, lab, details, ransac, res, ins: bool = False) -> dict:
    """Measured keypoint noise, the complete Cramér-Rao bound of the base pose, the model floor, their
    root-sum-square (the limit) and the ideal estimator's Monte Carlo.

    The bound (:func:`~bench.scenario.in_situ_bound.crb_base_pose`) has the observation pattern the matching
    produced (the map's surrounding views per point, the locate views where the final solve used the point), the
    measured keypoint noise, the encoders on every view, the identification's covariance of the arm errors, the
    camera calibration's covariance of ``fx, fy, cx, cy`` and the mount's (from the AX = XB residuals: ``rms^2 / n``
    per axis, rotation and translation). The floor (:func:`~bench.scenario.in_situ_bound.model_floor`) is the error on
    noise-free features through the true optics with the best central camera; ``base_*_bound_*`` is the limit
    ``sqrt(crb^2 + floor^2)``, ``base_*_crb_*`` the bound alone. With ``ins`` (the pipeline fused the vehicle's
    INS tilt) all of them take the INS's tilt at the vehicle section's accuracies by the same linear update
    (:class:`~bench.vision.tilt.TiltUpdate`, its gain the bound's): the bound's covariance ``(I - K H) C``, the
    floor's error ``(I - K H) e`` (a noise-free INS), each Monte Carlo draw's error with a draw of the INS;
    ``base_*_bound_vision_*`` is the limit without it."""
    from bench.scenario.in_situ_bound import (
        FIELD_DEGREES,
        crb_base_pose,
        keypoint_sigma_px,
        mc_ideal_estimator,
        model_floor,
        observation_pattern,
        track_noise_on_surface,
        track_pixels,
        true_projector,
    )
    from bench.sim.encoders import EncoderModel
    from bench.vision.insitu import one_per_detection

    lens, port, central = _true_optics(truth)
    poses = _true_camera_poses(robot, truth)
    obs = details["observations"]
    kmap = details["map"]
    ref = [n for n in obs if truth["views"][n]["role"] == "reference"][0]
    surround = [n for n in obs if truth["views"][n]["role"] == "surround"]
    pnp = cfg["pipeline"]["locate"] == "pnp"  # one locate view: the bound, floor and Monte Carlo of PnP
    loc = [n for n in obs if truth["views"][n]["role"] == "locate"][:1 if pnp else 2]
    profile = imaging(cfg)
    project = true_projector(lens, port, profile)
    sigma_px, n_sigma = keypoint_sigma_px(obs[ref], [obs[n] for n in surround], poses, lens, project, port=port)
    out = {"keypoint_sigma_px": sigma_px, "keypoint_sigma_matches": float(n_sigma)}
    if not np.isfinite(sigma_px) or sigma_px <= 0:
        return out
    # the locate views' own noise (the other parking's viewpoint), relative to the survey's on the same tracks, on the
    # panel's true surfaces; without a pose (no tracks), the survey's. Both as the Fisher information of the measured
    # errors' density has them (fisher_factor: the tails take a little from the core the robust sigma describes)
    ratio = points = f_survey = f_locate = float("nan")
    field = None  # the keypoints' error field per view (each degree's sd, measure_field), when measured
    if res.success and res.used is not None:
        from bench.scenario.scene_points import SceneRays

        surface = SceneRays(replay_panel(cfg), np.array(truth["T_world_panel"], float))
        tn = track_noise_on_surface(*track_pixels(kmap, res.used, obs, ref, surround, loc), poses[ref],
                                    np.stack([poses[n] for n in surround]), np.stack([poses[n] for n in loc]), lens,
                                    port, project, surface, cfg["bound"]["keypoint_field_order"])
        ratio, points, f_survey, f_locate = tn["ratio"], float(tn["points"]), tn["survey_fisher"], tn["locate_fisher"]
        degrees = FIELD_DEGREES[:len(tn["field_px"])]
        out.update({f"keypoint_field_{name}_px": float(sd) for name, sd in zip(degrees, tn["field_px"], strict=True)})
        out["keypoint_field_views"] = float(tn["field_views"])
        if cfg["bound"]["keypoint_field"] and tn["field_views"]:
            field = np.asarray(tn["field_px"], float)
    sigma_bound = sigma_px * _or_one(f_survey)
    sigma_loc = sigma_px * _or_one(ratio) * _or_one(f_locate)
    out.update({"keypoint_sigma_bound_px": sigma_bound, "keypoint_sigma_locate_px": sigma_loc,
                "keypoint_locate_ratio": ratio, "keypoint_locate_points": points, "keypoint_fisher_factor": f_survey,
                "keypoint_locate_fisher_factor": f_locate})
    T_wb1 = np.array(truth["T_world_base_survey"])
    T_site_b2 = invert(T_wb1) @ np.array(truth["T_world_base_locate"])
    # the features the pipeline found (linearisation), each detection once: SIFT's twin keypoints (two orientations at
    # one pixel) are one measurement, which the pipeline's map holds twice
    one, merge = one_per_detection(kmap)
    # the copies the map merged (pipeline.twin_keypoints once) or holds (both, weighted)
    out["keypoint_twin_points"] = float(kmap.stats.get("duplicate_detections", 0) + len(kmap) - len(one))
    X_site = transform_points(kmap.T_world_ref, kmap.p_ref[one])
    names = [ref, *surround, *loc]
    views = [(np.array(truth["views"][n]["q_true"]), n in loc) for n in names]
    sigma_views = np.array([sigma_loc if n in loc else sigma_bound for n in names])
    enc = truth["encoders"]
    sigma_enc = float(np.sqrt(enc["noise_std_rad"] ** 2 + enc["resolution_rad"] ** 2 / 12)) or 1e-9
    ident = lab["identification"]
    kept = closed_form_reduction(robot).kept
    eps_true, mount = np.array(truth["errors"]), np.array(truth["T_link5_cam"])
    p = cfg["pipeline"]
    thesis_refine = "bundle" if p["refine"] == "joints" else p["refine"]  # the joints are exact in these two
    floor = model_floor(robot, eps_true, mount, lens, port, T_site_b2, views, names, X_site, p["method"], ransac,
                        thesis_refine, profile=profile)
    cam, cal = floor["camera"], lab["camera"]
    # what the lab's calibrated central camera leaves on the same noise-free features (its mount by AX = XB on the
    # true arm, so that only the camera model differs): the central fit through the port at the rig's range
    nan = {"pos_m": float("nan"), "rot_rad": float("nan"), "xi": np.full(6, np.nan)}
    refractive = lab.get("refractive") is not None  # its floors are not a central camera's: not computed
    he_true = None if refractive else hand_eye_axxb(np.stack([link5_frame(robot, q, eps_true) for q in lab["rig_q"]]),
                                                    lab["T_cam_target"])
    floor_cal = model_floor(robot, eps_true, mount, lens, port, T_site_b2, views, names, X_site, p["method"], ransac,
                            thesis_refine, central=(cal.camera, invert(mount) @ he_true.T_mount_cam),
                            profile=profile) if he_true is not None and he_true.success else nan
    priors = lab["priors"]
    vis = (observation_pattern(kmap, len(names), res.used[0], len(loc)) @ merge  # seen where either twin was
           if res.success and res.used is not None else None)
    crb = crb_base_pose(robot, eps_true, kept, ident.covariance, mount @ floor["T_lens_central"], cam.project,
                        T_site_b2, views, X_site, cam.size, sigma_views, sigma_enc, K=cam.K, vis=vis, dist=cam.dist,
                        field=field, **priors)
    limit_vision = _limit(crb["cov"], floor, refractive)
    tilt_sd, heading_sd = _tilt_heading(crb["cov"][:3, :3], truth)
    out.update({"base_rot_crb_tilt_deg": np.rad2deg(tilt_sd), "base_rot_crb_heading_deg": np.rad2deg(heading_sd)})
    upd = _ins_update(cfg, truth, T_site_b2, crb["cov"]) if ins else None
    if upd is not None:
        crb = {**crb, "cov": upd.covariance(crb["cov"])}
        floor, floor_cal = ({**f, "xi": upd.error(f["xi"])} for f in (floor, floor_cal))
        for f in (floor, floor_cal):
            f["pos_m"], f["rot_rad"] = float(np.linalg.norm(f["xi"][3:])), float(np.linalg.norm(f["xi"][:3]))
    mc = mc_ideal_estimator(robot, eps_true, kept, ident.covariance, mount, central, T_site_b2, views, names, X_site,
                            sigma_views, EncoderModel(**enc), np.random.default_rng([cfg["seed"], 13]),
                            cfg["bound"]["mc_trials"], p["method"], ransac, thesis_refine, ins=upd, field=field)
    if cfg["bound"]["ml_trials"] > 0 and vis is not None and not pnp:  # the Monte Carlo of refine 'joints'
        from bench.scenario.in_situ_bound import mc_joint_bundle

        ml = mc_joint_bundle(robot, eps_true, kept, ident.covariance, mount @ floor["T_lens_central"], cam, T_site_b2,
                             views, X_site, vis, sigma_views, sigma_enc, np.random.default_rng([cfg["seed"], 14]),
                             cfg["bound"]["ml_trials"], ins=upd, field=field, **priors)
        out.update({"base_pos_crb_mc_mm": ml["pos_rms_m"] * 1e3, "base_rot_crb_mc_deg": np.rad2deg(ml["rot_rms_rad"])})
    if refractive:  # the floor above is the best central camera's (its camera and frame serve the CRB), not this one's
        floor = {**floor, **nan}
    cov = crb["cov"]
    limit = _limit(cov, floor, refractive)
    out.update({"base_pos_crb_mm": np.sqrt(np.trace(cov[3:, 3:])) * 1e3,
                "base_rot_crb_deg": np.rad2deg(np.sqrt(np.trace(cov[:3, :3]))),
                "base_pos_floor_mm": floor["pos_m"] * 1e3, "base_rot_floor_deg": np.rad2deg(floor["rot_rad"]),
                "floor_misfit_px": floor["misfit_px"], "base_pos_floor_calibrated_mm": floor_cal["pos_m"] * 1e3,
                "base_rot_floor_calibrated_deg": np.rad2deg(floor_cal["rot_rad"]),
                "base_pos_bound_mm": limit[0] * 1e3, "base_rot_bound_deg": np.rad2deg(limit[1]),
                "base_pos_bound_vision_mm": limit_vision[0] * 1e3,
                "base_rot_bound_vision_deg": np.rad2deg(limit_vision[1]),
                "base_pos_bound_mc_mm": mc["pos_rms_m"] * 1e3, "base_rot_bound_mc_deg": np.rad2deg(mc["rot_rms_rad"]),
                "bound_observations": float(crb["observations"])})
    return out


def _limit(cov, floor: dict, refractive: bool) -> tuple:
    """The limit ``(m, rad)``: the bound's covariance ``cov`` (6, 6) root-sum-squared with the floor's error
    (none for the refractive camera, or when its solve failed)."""
    f_pos, f_rot = (0.0 if refractive or not np.isfinite(v) else v for v in (floor["pos_m"], floor["rot_rad"]))
    return float(np.hypot(np.sqrt(np.trace(cov[3:, 3:])), f_pos)), float(np.hypot(np.sqrt(np.trace(cov[:3, :3])),
                                                                                  f_rot))


def _down_survey(truth) -> np.ndarray:
    """Gravity's direction (3,) in the true survey base frame (the site frame)."""
    from bench.sim.ins import DOWN_WORLD

    return np.array(truth["T_world_base_survey"], float)[:3, :3].T @ DOWN_WORLD


def _tilt_heading(cov_rot, truth) -> tuple:
    """A rotation covariance (3, 3; site frame) split about gravity: the RMS of its tilt (about the two horizontal
    axes together) and of its heading (about the vertical), rad."""
    d = _down_survey(truth)
    C = np.asarray(cov_rot, float)
    heading = float(d @ C @ d)
    return float(np.sqrt(max(np.trace(C) - heading, 0.0))), float(np.sqrt(max(heading, 0.0)))


def _ins_update(cfg, truth, T_site_b2, cov):
    """The INS tilt's :class:`~bench.vision.tilt.TiltUpdate` of the bound's covariance ``cov`` (6, 6): gravity in the
    true base frames at both parkings, the vehicle section's accuracies."""
    from bench.vision.tilt import VehicleTilt, tilt_update

    v, d = cfg["vehicle"], _down_survey(truth)  # gravity at the locate parking: the survey's, carried by the base
    tilt = VehicleTilt(d, T_site_b2[:3, :3].T @ d, float(np.deg2rad(v["tilt_sigma_deg"])),
                       float(np.deg2rad(v["alignment_sigma_deg"])))
    return tilt_update(T_site_b2[:3, :3], cov, tilt)


def _or_one(factor: float) -> float:
    """A measured factor, or 1 where it could not be measured (NaN, or not positive)."""
    return factor if np.isfinite(factor) and factor > 0 else 1.0


def _components(name, v, unit) -> dict:
    """``{name_x_unit: v[0], name_y_unit: v[1], name_z_unit: v[2]}``: a signed error vector as metrics."""
    return {f"{name}_{a}_{unit}": float(x) for a, x in zip("xyz", v, strict=True)}


def _score_task(cfg, ds, truth, report, robot):
    """Drive the true arm to the pipeline's commanded readings and measure the tool tip against the true handle.

    Returns the metrics and the true joint angles reached (``{"compensated": q, "uncompensated": q}``; a missing
    key: no command)."""
    from bench.sim.encoders import EncoderModel

    task = truth.get("task")
    if not task:
        return {}, {}
    nan = float("nan")
    t = report.get("tasks", {}).get(task["view"])
    enc = EncoderModel(**truth["encoders"])
    rng = np.random.default_rng([cfg["seed"], 7])
    eps_true = np.array(truth["errors"])
    T_wb2 = np.array(truth["T_world_base_locate"])
    p_valve = np.array(task["centre_world"])

    reached = {}

    def tip_error(key, q_cmd):  # the servos settle where the encoders read the command (noise, quantisation)
        reached[key] = enc.drive_to(q_cmd, rng)
        T = T_wb2 @ forward_kinematics(robot, reached[key], eps_true)
        return (transform_points(T, robot.p_ee) - p_valve) * 1e3

    out = {"valve_tool_err_uncompensated_mm": float(np.linalg.norm(tip_error("uncompensated",
                                                                                ds.view(task["view"]).q)))}
    ok = t and t["success"]
    e = tip_error("compensated", np.deg2rad(t["q_command_deg"])) if ok else np.full(3, nan)
    out["valve_tool_err_mm"] = float(np.linalg.norm(e))
    out.update(_components("valve_tool_err", e, "mm"))  # world frame: the budget's paired displacements
    pr = t.get("protection_radius_mm") if ok else None
    out["valve_protection_radius_mm"] = nan if pr is None else float(pr)
    return out, reached


# ------------------------------------------------------------------------------------------------ pipeline


def run(cfg, out_dir, verbose=True):
    """Render (cached) the campaign, run the pipeline on the dataset, score against the truth, write result.json."""
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    ds_dir = out_dir / "dataset"
    cache = out_dir.parent / ".render_cache" if cfg["outputs"]["cache"] else None
    checks = render(cfg, ds_dir, verbose=verbose, cache_dir=cache)
    t_render = time.perf_counter() - t0
    ds = load_dataset(ds_dir)
    robot = ds.robot()
    lab = calibrate_lab(ds, robot, cfg, out_dir / "calibrated")
    camera_path, robot_path, priors_path = _oracle_files(cfg, ds, robot, out_dir, lab)
    p = cfg["pipeline"]
    truth = yaml.safe_load((ds_dir / "truth" / "truth.yaml").read_text())  # the evaluator's
    ransac = dict(iterations=p["ransac_iterations"], d_r=p["d_r_mm"] * 1e-3, r_lim=p["r_lim"])
    features_fn = None
    map_cfg = twin_map_config(p["twin_keypoints"])
    if cfg["sources"]["features"] == "perfect":  # the real run's points and pattern (paired), exactly projected
        sift = {}
        res0, _ = locate_dataset(ds_dir, None, method=p["method"], seed=cfg["seed"], config=map_cfg,
                                 verbose=False, camera_path=camera_path, robot_path=robot_path, refine="pose",
                                 ransac=ransac, details=sift)
        features_fn = _perfect_features(cfg, robot, truth, sift, res0)
    details = {}
    res, report = locate_dataset(ds_dir, out_dir, method=p["method"], seed=cfg["seed"],
                                 config=map_cfg, verbose=False, camera_path=camera_path,
                                 robot_path=robot_path, refine=p["refine"], ransac=ransac, details=details,
                                 features_fn=features_fn, priors_path=priors_path, guided=p["guided"],
                                 loss=None if p["loss"] == "none" else p["loss"], map_points=p["map_points"],
                                 pnp=p["locate"] == "pnp", keypoints=p["keypoints"], ins_tilt=p["ins_tilt"],
                                 covariance=p["covariance"])

    # --- score (the evaluator reads the truth) ----------------------------------------------------------------------
    T_b1_b2 = invert(np.array(truth["T_world_base_survey"])) @ np.array(truth["T_world_base_locate"])
    metrics = dict(checks)
    metrics.update({k: float(report[k]) for k in ("map_points", "inliers")})
    # integrity (bench.vision.integrity): ok = 1; protection levels NaN when refused (no bound: do not use the pose)
    metrics.update({f"integrity_{v}": float(report["integrity"] == v) for v in ("ok", "refused")})
    for k in ("protection_radius_mm", "protection_angle_deg"):
        metrics[k] = float("nan") if report[k] is None else float(report[k])
    tilt = report["integrity_tests"].get("tilt_mahalanobis_sq")  # test 7 (bench.vision.tilt)
    metrics["integrity_tilt_sq"] = float("nan") if tilt is None else float(tilt)
    metrics["insitu_solve_s"] = float(sum(res.timings_s.get(k, 0.0) for k in ("match_s", "triangulate_s", "align_s",
                                                                                 "refine_s")))
    if res.success:
        T = res.T_world_base
        metrics["base_pos_err_mm"], metrics["base_rot_err_deg"] = pose_errors(T, T_b1_b2)
        # the signed errors in the survey base frame, for the budget's paired displacements (bench.scenario.budget)
        metrics.update(_components("base_pos_err", (T[:3, 3] - T_b1_b2[:3, 3]) * 1e3, "mm"))
        metrics.update(_components("base_rot_err", np.rad2deg(matrix_to_rotation_vector(
            T[:3, :3] @ T_b1_b2[:3, :3].T)), "deg"))
        T = np.array(report.get("T_world_base_vision", T))  # the images' pose, before the INS's tilt was fused
        metrics["base_pos_err_vision_mm"], metrics["base_rot_err_vision_deg"] = pose_errors(T, T_b1_b2)
        w = matrix_to_rotation_vector(T[:3, :3] @ T_b1_b2[:3, :3].T)  # its rotation error about gravity and across it
        heading = float(w @ _down_survey(truth))
        metrics["base_rot_err_vision_heading_deg"] = float(np.rad2deg(abs(heading)))
        metrics["base_rot_err_vision_tilt_deg"] = float(np.rad2deg(np.sqrt(max(w @ w - heading**2, 0.0))))
        std = np.sqrt(np.clip(np.diag(res.covariance), 0, None))
        metrics["base_pos_std_mm"] = float(np.linalg.norm(std[3:]) * 1e3)
        metrics["base_rot_std_deg"] = float(np.rad2deg(np.linalg.norm(std[:3])))
    else:
        metrics["base_pos_err_mm"] = metrics["base_rot_err_deg"] = float("nan")
        metrics["base_pos_err_vision_mm"] = metrics["base_rot_err_vision_deg"] = float("nan")
        metrics.update({**_components("base_pos_err", np.full(3, np.nan), "mm"),
                        **_components("base_rot_err", np.full(3, np.nan), "deg")})
    thesis = details.get("thesis_result")  # pipeline.refine = joints: the thesis estimator (bundle) beside it
    if thesis is not None and thesis.success:
        metrics["base_pos_err_bundle_mm"], metrics["base_rot_err_bundle_deg"] = pose_errors(thesis.T_world_base,
                                                                                            T_b1_b2)
    task_metrics, reached = _score_task(cfg, ds, truth, report, robot)
    metrics.update(task_metrics)
    if cfg["bound"]["enabled"] and "map" in details and len(details["map"]) >= 3:
        t_b = time.perf_counter()
        metrics.update(_bound(cfg, robot, truth, lab, details, ransac, res, report.get("ins_tilt") == "fused"))
        metrics["bound_s"] = time.perf_counter() - t_b
        # efficiency of this run: bound / achieved (over seeds: RMS bound / RMS error)
        for q, u in (("pos", "mm"), ("rot", "deg")):
            b, e = metrics.get(f"base_{q}_bound_{u}"), metrics.get(f"base_{q}_err_{u}")
            if b is not None and e is not None and e > 0:
                metrics[f"base_{q}_efficiency"] = b / e
    refr = lab.get("refractive")
    if refr is None:  # the central camera: against the paraxial equivalent of lens + port, its mount the
        cam_true, K_hat = np.array(truth["camera_K_effective"]), lab["camera"].K  # port's virtual centre
        Tm_true, rms = np.array(truth["T_link5_cam_effective"]), lab["camera"].rms_px
    else:  # the refractive camera: the lens against the true lens, its mount at the lens centre
        cam_true, K_hat = np.array(truth["camera_K"]), refr.camera.lens.K
        Tm_true, rms = np.array(truth["T_link5_cam"]), refr.rms_px
        port_true = _true_optics(truth)[1]  # its decentre absorbed into d0, as the calibration estimates it
        metrics["port_d0_err_mm"] = float(abs(refr.camera.port.d0 - port_true.axial_d0) * 1e3)
        metrics["port_d0_std_mm"] = refr.std("d0") * 1e3
        metrics["port_tilt_err_deg"] = float(np.rad2deg(np.linalg.norm(refr.camera.port.tilt - port_true.tilt)))
        metrics["reproj_rms_central_px"] = float(lab["camera"].rms_px)
    metrics["focal_err_pct"] = float(abs(K_hat[0, 0] / cam_true[0, 0] - 1) * 100)
    metrics["reproj_rms_px"] = float(rms)
    Tm_hat = lab["mount"].T_mount_cam
    metrics["mount_pos_err_mm"], rot = pose_errors(Tm_hat, Tm_true)
    metrics["mount_pos_err_lens_centre_mm"] = pose_errors(Tm_hat, np.array(truth["T_link5_cam"]))[0]
    metrics["mount_rot_err_deg"] = rot
    q_ho = load_robot(Path(cfg["_file"]).parent / cfg["robot"]).random_configurations(np.random.default_rng(1), 500)
    eps_true = np.array(truth["errors"])
    metrics["arm_heldout_rms_mm"] = float(np.sqrt(np.mean(np.sum(
        (ee_position(robot, q_ho, lab["eps"]) - ee_position(robot, q_ho, eps_true)) ** 2, axis=1))) * 1e3)
    timings = {"render_s": t_render, **lab["timings"], **{k: float(v) for k, v in res.timings_s.items()},
               "total_s": time.perf_counter() - t0}
    rows = {"base position (mm)": "base_pos_err_mm", "base rotation (deg)": "base_rot_err_deg",
            "tool tip on the valve (mm)": "valve_tool_err_mm",
            "tool tip, taught readings replayed (mm)": "valve_tool_err_uncompensated_mm",
            "mount position (mm)": "mount_pos_err_mm", "mount rotation (deg)": "mount_rot_err_deg",
            "focal length (%)": "focal_err_pct", "arm held-out RMS (mm)": "arm_heldout_rms_mm"}
    table = {"quantity": list(rows), "error": [metrics.get(k, float("nan")) for k in rows.values()]}
    sources = {"source": list(SOURCES), "setting": [cfg["sources"][k] for k in SOURCES]}
    write_table_csv(out_dir / "errors.csv", table)
    artifacts = {"dataset": "dataset", "locate": "locate.json", "calibrated_camera": "calibrated/camera.yaml",
                 "calibrated_robot": "calibrated/robot.yaml", "errors": "errors.csv"}
    if cfg["outputs"]["rerun"]:
        from bench.scenario.in_situ_recording import record_in_situ

        t_rr = time.perf_counter()
        record_in_situ(out_dir / "recording.rrd", cfg, ds, truth, lab, res, report, details, reached, metrics)
        timings["rerun_s"] = time.perf_counter() - t_rr
        artifacts["recording"] = "recording.rrd"
    path = write_result(out_dir, cfg["name"], cfg["seed"], metrics, {"errors": table, "sources": sources}, timings,
                        artifacts)
    if verbose:
        print(f"{cfg['name']} (seed {cfg['seed']}): {res.message}")
        print("\n".join(integrity_lines(report)))
        print("\n".join(summary_lines(metrics)))
    return path


def integrity_lines(report: dict) -> list:
    """The localisation's own verdict as ``bench locate`` states it (``locate.json``): integrity, protection levels
    and the reasons - what an operator must read before using the pose."""
    verdict = report.get("integrity", "?")
    radius, angle = report.get("protection_radius_mm"), report.get("protection_angle_deg")
    levels = ("" if radius is None or angle is None or not (np.isfinite(radius) and np.isfinite(angle))
              else f" (protection radius {radius:.3g} mm, angle {angle:.3g} deg)")
    return [f"integrity: {verdict.upper()}{levels}"] + [f"  - {r}" for r in report.get("integrity_reasons", [])]


def summary_lines(metrics: dict) -> list:
    """The metrics ``bench run`` prints, one line each; a metric the run could not measure says why (``render_fps``
    when every view came from the render cache) instead of printing ``nan``."""
    lines = []
    for k in ("base_pos_err_mm", "base_rot_err_deg", "base_pos_std_mm", "valve_tool_err_mm",
              "valve_protection_radius_mm", "valve_tool_err_uncompensated_mm", "map_points", "inliers",
              "insitu_solve_s", "mount_pos_err_mm", "mount_rot_err_deg", "focal_err_pct", "reproj_rms_px",
              "arm_heldout_rms_mm", "sim_vs_fk_max_err_m", "marker_projection_rms_px", "render_fps",
              "panel_sift_keypoints"):
        if k in metrics:
            lines.append(f"  {k:<28} {metrics[k]:.6g}")
        elif k == "render_fps":  # every view came from the render cache: nothing was timed
            lines.append(f"  {k:<28} not measured: all views came from the render cache (outputs.cache=false "
                         "renders them)")
    return lines
