"""Scenario kind ``xy_table``: the thesis's x-y table experiments (section 5.2.2, Tables 5-8; section 5.4, 11-14).

Simulation (``render``, also ``bench sim render``) writes one dataset, as the lab campaign would:

* ``calibration`` views - the two-plane rig photographed from a few directions (the camera is calibrated first, as
  in section 5.2.1 / 5.3);
* ``table`` views - the camera on the x-y table's rotary stage at the poses of Table 4 (web camera on the rotation
  axis, a reference object 700 mm ahead: ``sim.reference_object`` the desk robot in its lab corner that stands in for
  the thesis's MA 2000, :mod:`bench.sim.scenes.desk_robot`, or the manifold panel) or Table 10 (underwater camera
  100 mm off the axis, the rig 500 mm ahead), with the table's *readings* in ``table.csv``;
* ``camera.yaml`` (the nominal camera), ``table.yaml`` (the table's nominal geometry), ``target.yaml`` (the rig);
* ``truth/``: the table's positioning errors, the camera's true intrinsics and its true orientation/centre on the
  support (the bias ``R0`` of Eq. 197 and a centre offset), every true camera pose, the reference object's pose.

The truth differs from what the pipeline is told by: the table's positioning errors (scale, backlash,
orthogonality, wobble; :class:`~bench.sim.scenes.xy_table.TableModel`) and readout quantisation; the camera's bias
on its support; the true intrinsics (focal length, principal point, distortion) vs the nominal camera file; the
housing's glass (underwater optics: not a central camera); image noise and SIFT.

The pipeline (``run``) uses only the public part: camera calibration from the rig views (Heikkilä's model or the
pinhole, :mod:`bench.camera.calibration`), then :mod:`bench.vision.xy_table_positioning` - features, the thesis's
search for ``R0`` (Eq. 197-198), and for every intraocular distance and pair the map ``1p``, ``2p``, RANSAC and the
four alignment methods, and at ``pipeline.bundle_intraocular_mm`` the maximum-likelihood bundle beside them
(:mod:`bench.vision.xy_table_bundle`: ``R0``, the intrinsics and the distortion refined with the pair). The
evaluator scores each estimated position against the true camera centres (relative to the reference view's, in the
table's axes) and prints our four tables beside the thesis's, and the bundle's beside them.

Error sources can be switched off one at a time (``sim.*`` keys) and truth can be injected on the evaluator's side
(``pipeline.camera: truth``, ``pipeline.mount_bias: truth``, ``pipeline.features: true_projection``); every injection is
listed in ``result.json`` (``metrics.truth_injected`` and the ``setup`` table).
"""

from __future__ import annotations

import csv
import json
import sys
import time
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import Field, model_validator

from bench.camera.calibrate_dataset import load_target, load_target_tolerance
from bench.camera.calibration import calibrate_camera
from bench.camera.corners import EXTRACTORS
from bench.camera.io import camera_yaml_text
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
    PositiveNumber,
    RenderOutputs,
    ScenarioBase,
    Section,
    Vec2,
    Vec3,
    about,
    at_least,
    section,
)
from bench.dataset import DatasetWriter, load_dataset
from bench.errors import ConfigError
from bench.fileio import atomic_save_figure, headless_pyplot
from bench.geometry.transforms import homogeneous, invert, rot_x, rot_y, rot_z, rotation_angle, transform_points
from bench.scenario.bounds import true_projector
from bench.scenario.in_situ_lab import rig_corners
from bench.scenario.results import write_result, write_table_csv
from bench.scenario.scene_textures import naming_the_key, texture_paths
from bench.sim.campaign import CachedCamera
from bench.sim.imaging import draw_true_lens, profile_from_config, rig_errors, rig_target_yaml
from bench.vision.features import Features, detect_sift
from bench.vision.insitu import MapConfig
from bench.vision.triangulation import required_baseline
from bench.vision.xy_table_positioning import (
    PositioningConfig,
    corner_features,
    estimate_positions,
    load_table_spec,
    rig_corner_features,
    table_views,
)

DEG = np.pi / 180
DATA = Path(__file__).resolve().parents[2] / "scenarios" / "data"
THESIS_TABLES = {"table4": (DATA / "thesis_tables_5_8.csv", {"quaternion": 5, "quaternion_ratio": 6, "lms": 7,
                                                              "lms_ratio": 8}, "Figures 49-52"),
                 "table10": (DATA / "thesis_tables_11_14.csv", {"quaternion": 11, "quaternion_ratio": 12, "lms": 13,
                                                                "lms_ratio": 14}, "Figures 55-58")}
LABELS = {"quaternion": "RANSAC, quaternion", "quaternion_ratio": "RANSAC, quaternion, error-ratio elimination",
          "lms": "RANSAC, LMS", "lms_ratio": "RANSAC, LMS, error-ratio elimination",
          "bundle": "bundle: the pair, R0, intrinsics, distortion and points by maximum likelihood"}
THESIS_METHODS = ("quaternion", "quaternion_ratio", "lms", "lms_ratio")
CAMERA_CHOICES = ("calibrated", "nominal", "truth")
BIAS_CHOICES = ("estimated", "truth", "zero")
FEATURE_CHOICES = ("sift", "corners", "true_projection")

DISTANCES_MM = Annotated[list[PositiveNumber], Field(min_length=1)]


class Sim(Section):
    poses: Annotated[Literal["table4", "table10"], about("table4 (section 5.2.2) | table10 (section 5.4)")] = \
        "table4"
    positions: Annotated[list[PositiveInt], about("pose numbers to use (empty: all rows of the table)")] = []
    optics: Annotated[str, about("optics preset (bench.sim.optics_presets)")] = "air_webcam"
    port: Annotated[bool, about("keep the preset's housing glass (false: no port)")] = True
    sensor_noise: Annotated[bool, about("shot and read noise (false: noise-free 8-bit images)")] = True
    supersample: PositiveInt = 2
    imaging: Annotated[str, about("realistic | ideal (bench.sim.imaging)")] = "realistic"
    imaging_off: Annotated[list[str], about("stages of the realistic profile switched off (ablation)")] = []
    imaging_params: ImagingParams = {}
    reference_object: Annotated[Literal["panel", "robot", "rig"], about(
        "panel (manifold panel) | robot (desk robot in a lab) | rig")] = "panel"
    textures: Annotated[dict, about("panel face -> image file (bench.scenario.scene_textures)")] = {}
    reference_distance_mm: Annotated[float, Field(gt=0), at_least(100, "implausible: the unit is mm")] = 700.0
    panel_size_m: Vec2 = [0.8, 0.6]
    table_errors: Annotated[bool, about("random positioning errors of the table (false: exact table)")] = True
    table_readout: Annotated[Literal["steps", "exact"], about(
        "steps (the step the table is at) | exact (the carriage's position)")] = "steps"
    mount_bias_deg: Annotated[Vec3, about("true theta_x0, theta_y0, theta_z0 (Eq. 197)")] = [0.3, 6.2, -1.8]
    camera_centre_error_mm: Annotated[Vec3, about("true camera centre minus the nominal one (support)")] = [
        0.5, 0.3, 1.0]
    camera_centre_tolerance_mm: Annotated[NonNegFloat, about(
        "what table.yaml states of it (1 sigma per axis; 0: not stated)")] = 1.0
    focal_error_pct: Annotated[NonNegFloat, about("true intrinsics vs the nominal camera file (uniform +-)")] = 1.5
    principal_error_px: NonNegFloat = 4.0
    distortion_error_pct: NonNegFloat = 5.0
    calibration_views: Annotated[PositiveInt, about(
        "rig views for the camera calibration (thesis: the webcam's K the mean of seven single-view calibrations, "
        "section 5.2.1; the underwater camera's from one view, section 5.3)")] = 7
    calibration_distance_mm: PositiveFloat = 800.0
    true_projection_points: Annotated[PositiveInt, about(
        "points on the reference for pipeline.features = true_projection")] = 800


class Pipeline(Section):
    camera: Annotated[Literal[CAMERA_CHOICES], about(
        "calibrated (rig views) | nominal (camera.yaml) | truth (INJECTED)")] = "calibrated"
    camera_model: Annotated[Literal["heikkila", "radial", "pinhole"], about("calibration model")] = "pinhole"
    mount_bias: Annotated[Literal[BIAS_CHOICES], about(
        "estimated (Eq. 197-198 search) | truth (INJECTED) | zero")] = "estimated"
    bias_refine: Annotated[bool, about("finer second pass of the search")] = False
    bias_depth_statistic: Annotated[Literal["median", "mean"], about(
        "median (robust) | mean (the thesis's average, Eq. 197 search)")] = "median"
    features: Annotated[Literal[FEATURE_CHOICES], about(
        "sift | corners (rig) | true_projection (INJECTED)")] = "sift"
    keypoints: Annotated[Literal["sift", "aligned"], about(
        "features = sift: SIFT's keypoints (the thesis's) or aligned - every view's keypoint matched to a reference "
        "keypoint moved onto the reference's image patch (bench.vision.patch_align; docs/bounds.md measures it)")] = \
        "sift"
    corner_extractor: Annotated[Literal[EXTRACTORS], about(
        "features = corners: opencv | thesis | thesis_printed (edge pixels)")] = "opencv"
    calibration_corner_extractor: Annotated[Literal[EXTRACTORS], about(
        "the rig's corners in the calibration views, as above")] = "opencv"
    reference_view: int = 11
    intraocular_mm: DISTANCES_MM = [20, 30, 40, 50, 60, 70, 80, 90, 100, 110]
    map_min_baseline_mm: Annotated[NonNegFloat, about("Eq. 199")] = 49.0
    map_exclude: Annotated[list[PositiveInt], about("pose numbers never used for 1p")] = []
    range_mm: Annotated[PositiveFloat, about("for the Eq. 199 figure reported with the calibrated camera")] = 700.0
    depth_resolution_mm: PositiveFloat = 10.0
    orientation_tol_deg: PositiveFloat = 20.0
    gap_mm: PositiveFloat = 5.0
    ransac_iterations: PositiveInt = 100
    d_r_mm: PositiveFloat = 20.0
    r_lim: PositiveFloat = 0.1
    bundle: Annotated[bool, about("the ML bundle beside the four (bench.vision.xy_table_bundle)")] = True
    bundle_intraocular_mm: Annotated[list[Number], about(
        "d_o (among intraocular_mm) where it runs too (~0.3 s each)")] = [50, 100]
    bundle_distortion_sigma: Annotated[list[PositiveNumber], about(
        "k1 k2 p1 p2 (8: and the thin prism s1..s4)")] = [0.3, 0.3, 0.03, 0.03]
    bundle_readings: Annotated[bool, about("also refine every view's reading (prior: one resolution step)")] = \
        False
    bundle_centre: Annotated[bool, about("also refine the camera centre (prior: table.yaml's tolerance)")] = False

    @model_validator(mode="after")
    def _bundle(self):
        bad = [x for x in self.bundle_intraocular_mm if not any(abs(x - y) < 1e-9 for y in self.intraocular_mm)]
        if self.keypoints != "sift" and self.features != "sift":
            raise KeyProblem("keypoints", f"used only by features 'sift', got features {self.features!r}")
        if self.bundle and bad:
            raise KeyProblem("bundle_intraocular_mm", f"{bad[0]!r} is not among pipeline.intraocular_mm "
                                                      f"({', '.join(f'{y:g}' for y in self.intraocular_mm)})")
        if len(self.bundle_distortion_sigma) not in (0, 4, 8):
            raise KeyProblem("bundle_distortion_sigma", f"expected [], four standard deviations > 0 (k1, k2, p1, p2) "
                                                        f"or eight (and the thin prism's s1..s4), got "
                                                        f"{self.bundle_distortion_sigma!r}")
        return self


class Bound(Section):
    """The Cramér-Rao bound of every estimate and a Monte Carlo of the ideal estimator (xy_table_bound)."""

    enabled: bool = True
    mc_trials: NonNegInt = 2
    mc_intraocular_mm: list[PositiveNumber] = [50, 100]


class Scenario(ScenarioBase):
    """An ``xy_table`` scenario file."""

    sim: Sim = section(Sim)
    pipeline: Pipeline = section(Pipeline)
    bound: Bound = section(Bound)
    outputs: RenderOutputs = section(RenderOutputs)

    @model_validator(mode="after")
    def _across(self):
        if self.pipeline.features == "corners" and self.sim.reference_object != "rig":
            raise KeyProblem("pipeline.features", "corners need the rig as reference object (sim.reference_object)")
        if self.pipeline.bundle and self.pipeline.bundle_centre and not self.sim.camera_centre_tolerance_mm > 0:
            raise KeyProblem("pipeline.bundle_centre", "needs the centre's tolerance (sim.camera_centre_tolerance_mm "
                                                       "> 0, written to table.yaml)")
        return self


# the error budget (bench budget): each source switched off in turn; the primary metric first
BUDGET = {"features": {"pipeline.features": "true_projection"},
          "optics_model": {"pipeline.camera": "truth", "sim.port": False},
          "kinematics": {"sim.table_errors": False, "pipeline.mount_bias": "truth",
                         "sim.camera_centre_error_mm": [0.0, 0.0, 0.0]},
          "encoders": {"sim.table_readout": "exact"}}
BUDGET_METRICS = ["lms_ratio_err_pos_at_100_mm", "lms_ratio_err_x_mm_at_100", "lms_ratio_err_y_mm_at_100",
                  "lms_ratio_err_z_mm_at_100"]
BUDGET_FIXED = {"outputs.plots": False, "outputs.rerun": False, "bound.enabled": False}


# ------------------------------------------------------------------------------------------------ configuration


def imaging(cfg):
    """The scenario's imaging profile (``sim.imaging``, ``sim.imaging_off``: :mod:`bench.sim.imaging`)."""
    return profile_from_config(cfg, "sim")


def _positions(cfg, n_rows: int) -> list:
    """The pose numbers of ``sim.positions`` (all ``n_rows`` when empty), sorted; they must hold the reference."""
    numbers = list(range(1, n_rows + 1))
    chosen = cfg["sim"]["positions"] or numbers
    bad = [n for n in chosen if n not in numbers]
    if bad:
        raise ConfigError(cfg["_file"], "sim.positions", f"pose {bad[0]} is not in {cfg['sim']['poses']} "
                                                         f"(1..{n_rows})")
    if cfg["pipeline"]["reference_view"] not in chosen:
        raise ConfigError(cfg["_file"], "pipeline.reference_view",
                          f"pose {cfg['pipeline']['reference_view']} is not among sim.positions")
    return sorted(set(chosen))


def validate(cfg) -> None:
    """The checks the model cannot make (the imaging profile, the texture files, the pose numbers against the pose
    table), before anything is created (runner, sweeps)."""
    from bench.sim.scenes.xy_table import TABLE4_CSV, TABLE10_CSV, load_pose_table

    imaging(cfg)
    texture_paths(cfg, "sim.textures")
    path = TABLE4_CSV if cfg["sim"]["poses"] == "table4" else TABLE10_CSV
    _positions(cfg, len(load_pose_table(path)["position"]))


def _campaign(cfg, rng):
    """``(pose numbers, TableModel, TableRun)``: the chosen poses of Table 4 / 10 in the order visited, the table
    (random positioning errors unless ``sim.table_errors`` is false) and what it did (truth and readings)."""
    from bench.sim.scenes.xy_table import (
        NO_ERRORS,
        lab_table_model,
        random_table_errors,
        table4_commands,
        table10_commands,
        underwater_table_model,
    )

    s = cfg["sim"]
    commands = table4_commands() if s["poses"] == "table4" else table10_commands()
    chosen = _positions(cfg, len(commands))
    errors = random_table_errors(rng) if s["table_errors"] else NO_ERRORS
    model = (lab_table_model if s["poses"] == "table4" else underwater_table_model)(errors)
    return chosen, model, model.run(commands[np.array(chosen) - 1])


def view_name(number: int) -> str:
    """Dataset name of the table view of pose ``number`` (``p01`` ...)."""
    return f"p{number:02d}"


# ------------------------------------------------------------------------------------------------ rendering


class OpticsCamera(CachedCamera):
    """A MuJoCo camera rendered through the optics chain of a preset, cached on disk by content hash
    (:class:`~bench.sim.campaign.CachedCamera`, as :class:`~bench.sim.campaign.ArmScene` renders the arm's camera).

    ``make_scene(spec)`` returns the ``MjSpec`` of a composed scene holding the MuJoCo camera ``name`` made by
    :func:`~bench.sim.camera.add_opencv_camera` for the render ``spec`` (its K and size); :meth:`render` takes a
    function that sets the state of ``MjData`` and a key that determines that state.
    """

    def __init__(self, make_scene, lens: CameraModel, optics, supersample: int, cache_dir=None, name="cam",
                 z_min: float = 0.3, imaging=None):
        super().__init__(lens, supersample, optics.port, z_min)
        self.lens, self.optics, self.name = lens, optics, name
        self._start_cache(make_scene(self.spec).compile(), optics.chain, imaging, cache_dir)

    def render(self, set_state, state_key, seed: int) -> np.ndarray:
        """RGB uint8 (camera size) with the state set by ``set_state(model, data)``; cached by ``state_key``."""
        return self._render(self.name, set_state, state_key, seed)


def _optics(cfg):
    from bench.sim.optics_presets import optics_preset

    s = cfg["sim"]
    overrides = {} if s["port"] else {"port": None, "water": None, "light": None}  # the water needs the port
    if not s["sensor_noise"]:
        overrides["sensor"] = None
    try:
        return optics_preset(s["optics"], overrides or None)
    except ValueError as exc:
        raise ConfigError(cfg["_file"], "sim.optics", str(exc)) from None


def _true_camera(cfg, rng, lens: CameraModel) -> CameraModel:
    s = cfg["sim"]
    return draw_true_lens(lens, rng, imaging(cfg), s["focal_error_pct"], s["principal_error_px"],
                          s["distortion_error_pct"])


def _calibration_poses(n, distance_m, rng):
    """``T_rig_cam`` of ``n`` rig views: looking at the rig centre from azimuths +-25 deg, elevations +-12 deg,
    rolls +-8 deg (the rig frame: :func:`~bench.sim.scenes.xy_table.reference_pose` seen from the table)."""
    from bench.sim.views import look_at

    az = np.linspace(-25, 25, n) * DEG if n > 1 else np.zeros(1)
    el = 12 * DEG * np.sin(np.linspace(0, 2 * np.pi, n, endpoint=False))
    roll = 8 * DEG * np.cos(np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.7)
    out = []
    for k in range(n):
        d = distance_m * (1 + 0.08 * rng.uniform(-1, 1))
        direction = np.array([np.sin(az[k]) * np.cos(el[k]), -np.sin(el[k]), np.cos(az[k]) * np.cos(el[k])])
        T = look_at(-d * direction, np.zeros(3), down=(0.0, 1.0, 0.0))  # table-like frame: y down
        T[:3, :3] = T[:3, :3] @ rot_z(roll[k])
        out.append(T)
    return out


def reference_object(cfg, rng):
    """The reference object as :func:`render` draws it, from ``rng`` in the state render has it there: the textured
    manifold panel (``sim.reference_object: panel``, a seeded draw), the desk robot in its lab (``robot``: relief,
    specular metal, a lamp; :mod:`bench.sim.scenes.desk_robot`) or the rig with its printing errors."""
    from bench.sim.scenes.desk_robot import desk_robot
    from bench.sim.scenes.panel import manifold_panel
    from bench.sim.scenes.rig import calibration_rig

    if cfg["sim"]["reference_object"] == "robot":
        with naming_the_key(cfg, "sim.textures"):
            return desk_robot(rng, name="ref", texture_overrides=texture_paths(cfg, "sim.textures"))

    if cfg["sim"]["reference_object"] == "panel":
        w, h = np.array(cfg["sim"]["panel_size_m"], float)
        try:
            with naming_the_key(cfg, "sim.textures"):
                return manifold_panel(rng, w, h, name="ref", texture_overrides=texture_paths(cfg, "sim.textures"))
        except ValueError as exc:
            raise ConfigError(cfg["_file"], "sim.panel_size_m", str(exc)) from None
    return calibration_rig(name="ref", errors=rig_errors(imaging(cfg), cfg["seed"], 0x7A13))


def replay_reference_object(cfg, truth: dict):
    """The reference object of a rendered campaign, drawn again from the scenario's seed exactly as :func:`render`
    drew it (the table's and the lens's draws first); None when the replay is out of step with the dataset (its
    true camera matrix is not ``truth["camera_K"]``, e.g. a dataset rendered by another version)."""
    rng = np.random.default_rng(cfg["seed"])
    _campaign(cfg, rng)
    lens = _true_camera(cfg, rng, load_preset(_optics(cfg).lens_camera))
    if not np.array_equal(lens.K, np.array(truth["camera_K"], float)):
        return None
    return reference_object(cfg, rng)


def render(cfg, out_dataset, verbose=True, cache_dir=None) -> dict:
    """Simulate the campaign and write the dataset (with ``truth/``); returns the simulator's figures."""
    from bench.sim.camera import add_opencv_camera
    from bench.sim.scenes.base import compose, place
    from bench.sim.scenes.rig import calibration_rig
    from bench.sim.scenes.xy_table import DEFAULT_T_WORLD_TABLE, reference_pose, xy_table

    t0 = time.perf_counter()
    s = cfg["sim"]
    rng = np.random.default_rng(cfg["seed"])
    numbers, tm, run = _campaign(cfg, rng)
    errors = tm.errors
    optics = _optics(cfg)
    profile = imaging(cfg)
    nominal_cam = load_preset(optics.nominal_camera)
    lens = _true_camera(cfg, rng, load_preset(optics.lens_camera))
    b = np.array(cfg["sim"]["mount_bias_deg"], float) * DEG
    R0_true = rot_y(b[1]) @ rot_x(b[0]) @ rot_z(b[2])  # Eq. 197, factors as labelled
    T_mount_cam = homogeneous(R0_true, np.array(cfg["sim"]["camera_centre_error_mm"], float) * 1e-3)
    ref_obj = reference_object(cfg, rng)
    # the experimenter puts the object where the camera sees it: its centre (the panel's face centre, the rig's
    # pattern centroid) on the reference view's TRUE optical axis, reference_distance_mm from the camera centre;
    # its orientation faces the table (-z), as reference_pose() sets it
    dist_m = s["reference_distance_mm"] * 1e-3
    T_ref_cam = run.T_table_mount[numbers.index(cfg["pipeline"]["reference_view"])] @ T_mount_cam
    aim = T_ref_cam[:3, 3] + dist_m * T_ref_cam[:3, 2]
    T_table_ref = reference_pose(ref_obj, dist_m, float(tm.camera_offset_m[0]))
    centre = transform_points(T_table_ref, ref_obj.features["corners"]).mean(axis=0) \
        if s["reference_object"] == "rig" else T_table_ref[:3, 3]
    T_table_ref[[0, 2], 3] += aim[[0, 2]] - centre[[0, 2]]
    z_min = 0.5 * min(dist_m, s["calibration_distance_mm"] * 1e-3)

    def table_scene(spec):
        def cam(body):
            add_opencv_camera(body, "xy_cam", spec.K, spec.width, spec.height, T_mount_cam)
        obj = xy_table(tm, cam, reference=ref_obj, T_table_reference=T_table_ref)
        return compose([obj], offscreen=(spec.width, spec.height), center=(0.0, dist_m / 2, 0.4), extent=2.0)

    # the calibration rig (a scene of its own) stands as it would in front of the table; views around its centre
    rig = calibration_rig(name="calrig", errors=rig_errors(profile, cfg["seed"]))
    T_table_rig = reference_pose(rig, 1.0)
    T_world_rig = DEFAULT_T_WORLD_TABLE @ T_table_rig
    c_table = transform_points(T_table_rig, rig.features["corners"]).mean(axis=0)
    cal_poses = _calibration_poses(s["calibration_views"], s["calibration_distance_mm"] * 1e-3, rng)
    T_world_cal = [DEFAULT_T_WORLD_TABLE @ homogeneous(np.eye(3), c_table) @ T for T in cal_poses]

    def cal_scene(spec):
        def extra(scene):
            body = scene.worldbody.add_body(name="calcam", mocap=True)
            add_opencv_camera(body, "xy_cam", spec.K, spec.width, spec.height, np.eye(4))
        return compose([place(rig, T_world_rig)], extra, offscreen=(spec.width, spec.height),
                       center=T_world_rig[:3, 3], extent=2.0)

    scene = OpticsCamera(table_scene, lens, optics, s["supersample"], cache_dir, "xy_cam", z_min, profile)
    cal_scene = OpticsCamera(cal_scene, lens, optics, s["supersample"], cache_dir, "xy_cam", z_min, profile)
    jadr = [scene.model.joint(n).qposadr[0] for n in tm.joint_names]
    images = {}
    n_total = len(numbers) + len(cal_poses)
    if verbose:
        print(f"rendering {n_total} views ({len(cal_poses)} calibration, {len(numbers)} table) ...", file=sys.stderr)
    from bench.geometry.quaternion import matrix_to_quaternion

    for k, T_w in enumerate(T_world_cal):

        def set_cal(model, data, T_w=T_w):
            data.mocap_pos[0] = T_w[:3, 3]
            data.mocap_quat[0] = matrix_to_quaternion(T_w[:3, :3])

        images[f"cal{k + 1:02d}"] = cal_scene.render(set_cal, T_w.ravel(), cfg["seed"] * 1000 + 500 + k)
        if verbose:
            print(f"\r  {k + 1}/{n_total}", end="", file=sys.stderr)
    q_table = np.stack([run.qpos[n] for n in tm.joint_names], -1)
    for i, num in enumerate(numbers):
        def set_table(model, data, q=q_table[i]):
            data.qpos[jadr] = q

        images[view_name(num)] = scene.render(set_table, q_table[i], cfg["seed"] * 1000 + num)
        if verbose:
            print(f"\r  {len(cal_poses) + i + 1}/{n_total}", end="", file=sys.stderr)
    if verbose:
        print(file=sys.stderr)
    render_s = scene.render_s + cal_scene.render_s
    scene.close()
    cal_scene.close()

    # --- truth ------------------------------------------------------------------------------------------------------
    # the readings: the step the table is at (its controller's display, quantised to the resolution; the carriage is
    # off it by the positioning errors) or, sim.table_readout = exact, where the carriage truly is along each axis
    readings = run.true if s["table_readout"] == "exact" else run.read
    T_table_cam = run.T_table_mount @ T_mount_cam
    centre_err = np.linalg.norm(T_table_cam[:, :3, 3] - run.T_table_mount_nominal[:, :3, 3], axis=1)
    truth = {
        "units": "SI (m, rad)",
        "poses": s["poses"], "positions": numbers,
        "table_errors": {k: float(v) for k, v in errors.__dict__.items()},
        "commanded": run.commanded.tolist(), "steps": run.read.tolist(), "read": readings.tolist(),
        "true_joints": run.true.tolist(), "table_readout": s["table_readout"],
        "T_table_mount": run.T_table_mount.tolist(),
        "T_mount_cam": T_mount_cam.tolist(),
        "mount_bias_deg": np.array(cfg["sim"]["mount_bias_deg"], float).tolist(),
        "T_table_cam": {view_name(n): T_table_cam[i].tolist() for i, n in enumerate(numbers)},
        "camera_offset_m": tm.camera_offset_m.tolist(),
        "camera_K": lens.K.tolist(), "camera_dist": lens.dist.tolist(), "camera_size": list(lens.size),
        "optics": {"preset": optics.name, "port": None if optics.port is None else {
            "d0": optics.port.d0, "t": optics.port.t, "n_air": optics.port.n_air, "n_glass": optics.port.n_glass,
            "n_water": optics.port.n_water, "tilt": optics.port.tilt.tolist(),
            "decentre": optics.port.decentre.tolist()}},
        "reference_object": s["reference_object"], "T_table_reference": T_table_ref.tolist(),
        "reference_corners": ref_obj.features["corners"].tolist() if s["reference_object"] == "rig" else None,
        "panel_size_m": [float(x) for x in s["panel_size_m"]] if s["reference_object"] == "panel" else None,
        "calibration": {"T_world_rig": T_world_rig.tolist(),
                        "T_world_cam": {f"cal{k + 1:02d}": T.tolist() for k, T in enumerate(T_world_cal)}},
    }
    checks = {"views_rendered": float(len(render_s)),
              "camera_centre_vs_readings_max_mm": float(centre_err.max() * 1e3),
              "sim_s": time.perf_counter() - t0}
    if render_s:
        checks["render_fps"] = float(1.0 / np.median(render_s))

    # --- the dataset --------------------------------------------------------------------------------------------------
    out_dataset = Path(out_dataset)
    spec_yaml = (f"# nominal geometry of the x-y table (thesis section 5.2 / 5.4)\n"
                 f"camera_offset_mm: {[float(v) for v in tm.camera_offset_m * 1e3]}\n"
                 f"travel_mm: {tm.travel_m * 1e3:g}\nresolution_mm: {tm.resolution_m * 1e3:g}\n"
                 f"resolution_deg: {np.rad2deg(tm.resolution_rad):g}\n")
    if s["camera_centre_tolerance_mm"] > 0:  # how well the lab knows where the camera centre sits on the stage
        spec_yaml += f"camera_offset_tolerance_mm: {s['camera_centre_tolerance_mm']:g}\n"
    with DatasetWriter(out_dataset, kind="xy_table", name=cfg["name"], overwrite=True,
                       command="sim render", identity=cfg["name"],
                       created_by=f"bench sim render {Path(cfg['_file']).name} (seed {cfg['seed']})") as w:
        for k in range(len(cal_poses)):
            w.add_view(f"cal{k + 1:02d}", images[f"cal{k + 1:02d}"], role="calibration")
        for i, num in enumerate(numbers):
            w.add_view(view_name(num), images[view_name(num)], table=readings[i], role="table",
                       notes=f"{s['poses']} position {num}")
        w.write_text("camera.yaml", camera_yaml_text(nominal_cam))
        w.write_text("table.yaml", spec_yaml)
        w.write_text("target.yaml", rig_target_yaml(profile))  # the rig's stated print tolerances
        w.write_text("truth/truth.yaml", yaml.safe_dump(truth, sort_keys=False))
        w.write_text("truth/sim_checks.json", json.dumps(checks, indent=2) + "\n")
    if verbose:
        print(f"wrote {out_dataset} ({len(numbers)} table views, {len(cal_poses)} calibration views)")
    return checks


# ------------------------------------------------------------------------------------------------ pipeline side


def calibrate_from_rig_views(ds, model: str, tolerance_draws: int = 48, extractor: str = "opencv"):
    """Corners (``extractor``: ``opencv | thesis | thesis_printed``, ``target.yaml``) in the ``calibration`` views ->
    :func:`calibrate_camera`.

    Returns ``(calibration, views used, cov_K)``: ``cov_K`` (4, 4) px^2 is the covariance of ``fx, fy, cx, cy`` -
    the calibration's own (its corner noise) plus, when ``target.yaml`` states the rig's tolerances, what they leave
    in it (the second moment of ``tolerance_draws`` calibrations of the same detections against rigs drawn from them:
    :func:`bench.camera.target_tolerance.calibration_with_tolerance`; the in-situ lab step does the same through
    :func:`~bench.camera.target_tolerance.consider_covariance` with the mount in its solve).
    """
    from bench.camera.target_tolerance import calibration_with_tolerance

    geometry = load_target(ds.root / "target.yaml")
    # one view of the two-plane rig determines the camera (section 5.3 calibrated the underwater camera from one); a
    # planar target's single view is calibrate_camera's one-line failure
    Xs, uvs, _, size = rig_corners(ds, geometry, extractor, "calibration", need=1)
    cal = calibrate_camera(Xs, uvs, size, model=model)
    if not cal.success:
        raise ConfigError(ds.root, "calibration views", f"camera calibration failed: {cal.message}")
    tolerance = load_target_tolerance(ds.root / "target.yaml")
    cov = cal.covariance
    if tolerance is not None and tolerance.any and tolerance_draws > 0:
        cov = calibration_with_tolerance(cal, geometry, tolerance, Xs, uvs, tolerance_draws,
                                         ds.root / "target.yaml")[0].covariance
    i_K = [cal.parameter_names.index(n) for n in ("fx", "fy", "cx", "cy")]
    return cal, len(Xs), np.asarray(cov, float)[np.ix_(i_K, i_K)]


def true_optics(truth: dict) -> tuple:
    """EVALUATOR SIDE: ``(lens, port)`` - the true lens (a :class:`CameraModel`) and the housing's flat port (None
    without one) from ``truth.yaml``; :func:`bench.scenario.bounds.true_projector` projects through both."""
    from bench.camera.flatport import FlatPort

    lens = CameraModel(int(truth["camera_size"][0]), int(truth["camera_size"][1]), np.array(truth["camera_K"]),
                       np.array(truth["camera_dist"]), name="true lens")
    pd = truth["optics"]["port"]
    port = None if pd is None else FlatPort(d0=pd["d0"], t=pd["t"], n_air=pd["n_air"], n_glass=pd["n_glass"],
                                            n_water=pd["n_water"], tilt=np.array(pd["tilt"]),
                                            decentre=np.array(pd["decentre"]))
    return lens, port


def true_projection_features(truth: dict, names, n_points: int, rng, profile=None, reference=None) -> dict:
    """EVALUATOR-SIDE TRUTH INJECTION: exact projections of known points on the reference object as features, through
    the true optics (lens, port, and a realistic imaging ``profile``'s static warp, as the renders have it).

    Rig: its 72 corners (ids as descriptors). Panel: ``n_points`` points drawn on the backplate plane (panel z = 0,
    inside its outline) with random unit descriptors (occlusion by the valves is ignored). Desk robot (``reference``,
    the replayed :class:`~bench.sim.scenes.base.SceneObject`): the surfaces that ``n_points`` rays of the reference
    view's camera first meet, each kept in a view only where nothing occludes it
    (:class:`~bench.scenario.scene_points.SceneRays`). Points outside an image or behind the camera are left out of
    that view. Removes detection noise and false matches.
    """
    T_tr = np.array(truth["T_table_reference"])
    lens, port = true_optics(truth)
    project = true_projector(lens, port, profile)
    T_tc = {n: np.array(truth["T_table_cam"][n]) for n in names}
    rays = None
    if truth["reference_object"] == "robot":
        from bench.scenario.scene_points import SceneRays

        if reference is None:
            raise ValueError("true_projection on the desk robot needs its replayed scene object")
        rays = SceneRays(reference, T_tr)
        ref = min(names, key=lambda n: np.linalg.norm(T_tc[n][:3, 3]))  # the table's centre view
        p_table = rays.surface_points(T_tc[ref], lens, port, n_points, rng)
        desc = rng.normal(size=(len(p_table), 128)).astype(np.float32)
        desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    elif truth["reference_corners"] is not None:
        p_obj = np.array(truth["reference_corners"])
        ids = np.arange(len(p_obj))
        desc = corner_features(np.zeros((len(ids), 2)), ids, len(ids)).descriptors
    else:
        w, h = truth["panel_size_m"]
        p_obj = np.c_[rng.uniform(-0.45 * w, 0.45 * w, n_points), rng.uniform(-0.45 * h, 0.45 * h, n_points),
                      np.zeros(n_points)]
        desc = rng.normal(size=(n_points, 128)).astype(np.float32)
        desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    if rays is None:
        p_table = transform_points(T_tr, p_obj)
    out = {}
    for n in names:
        p_cam = transform_points(invert(T_tc[n]), p_table)
        front = p_cam[:, 2] > 0.05
        if rays is not None:
            front &= rays.visible(p_table, T_tc[n][:3, 3])
        uv = np.full((len(p_cam), 2), np.nan)
        uv[front] = project(p_cam[front])
        ok = front & np.all(np.isfinite(uv), axis=1) & lens.in_image(np.nan_to_num(uv, nan=-1e9))
        k = np.count_nonzero(ok)
        out[n] = Features(uv[ok], np.zeros(k), np.full(k, 4.0), np.ones(k), desc[ok])
    return out


# ------------------------------------------------------------------------------------------------ scoring / report


def load_thesis_table(poses: str) -> dict:
    """The thesis's printed table rows ``{(method, d_mm): row}`` (``scenarios/data/thesis_tables_*.csv``)."""
    path, _, _ = THESIS_TABLES[poses]
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    out = {}
    for row in csv.DictReader(lines):
        out[(row["method"], float(row["d_mm"]))] = {
            "table": int(row["table"]), "combinations": int(row["combinations"]),
            **{k: float(row[k]) for k in ("err_x_mm", "err_y_mm", "err_z_mm")}}
    return out


def score(result, truth: dict, reference: str, methods) -> tuple:
    """Per-combination errors (estimated minus true position of camera a relative to the reference, table axes) and
    the RMS table per (d_o, method). Returns ``(per_combination table, summary table)``."""
    T_tc = {n: np.array(T) for n, T in truth["T_table_cam"].items()}
    c_ref = T_tc[reference][:3, 3]
    rows = {k: [] for k in ("d_mm", "a", "b", "method", "success", "est_x_mm", "est_y_mm", "est_z_mm", "true_x_mm",
                            "true_y_mm", "true_z_mm", "err_x_mm", "err_y_mm", "err_z_mm", "baseline_mm", "map_points",
                            "pairs_3d", "ransac_inliers", "inliers")}
    for c in result.combinations:
        true = (T_tc[c.a][:3, 3] - c_ref) * 1e3
        est = c.p_table * 1e3
        for key, val in (("d_mm", c.d_m * 1e3), ("a", c.a), ("b", c.b), ("method", c.method),
                         ("success", int(c.success)), ("baseline_mm", np.linalg.norm(T_tc[c.a][:3, 3] -
                                                                                      T_tc[c.b][:3, 3]) * 1e3),
                         ("map_points", c.map_points), ("pairs_3d", c.pairs_3d),
                         ("ransac_inliers", c.ransac_inliers), ("inliers", c.inliers)):
            rows[key].append(val)
        for i, ax in enumerate("xyz"):
            rows[f"est_{ax}_mm"].append(float(est[i]))
            rows[f"true_{ax}_mm"].append(float(true[i]))
            rows[f"err_{ax}_mm"].append(float(est[i] - true[i]))
    summary = {k: [] for k in ("d_mm", "method", "combinations", "failed", "err_x_mm", "err_y_mm", "err_z_mm",
                               "err_pos_mm", "mean_baseline_mm")}
    d_all = np.array(rows["d_mm"], float)
    meth = np.array(rows["method"], object)
    ok = np.array(rows["success"], bool)
    err = np.stack([np.array(rows[f"err_{a}_mm"], float) for a in "xyz"], -1) if rows["d_mm"] else np.empty((0, 3))
    base = np.array(rows["baseline_mm"], float)
    for d in sorted(result.pairs):
        for m in methods:
            sel = (np.abs(d_all - d) < 1e-6) & (meth == m)
            if not sel.any():  # a method not run at this d_o (the bundle's pipeline.bundle_intraocular_mm)
                continue
            good = sel & ok
            rms = np.sqrt(np.mean(err[good] ** 2, axis=0)) if good.any() else np.full(3, np.nan)
            summary["d_mm"].append(float(d))
            summary["method"].append(m)
            summary["combinations"].append(len(result.pairs[d]))
            summary["failed"].append(int(np.count_nonzero(sel & ~ok)))
            for i, ax in enumerate("xyz"):
                summary[f"err_{ax}_mm"].append(float(rms[i]))
            summary["err_pos_mm"].append(float(np.sqrt(np.sum(rms**2))))  # 3D RMS over the combinations
            summary["mean_baseline_mm"].append(float(base[sel].mean()) if sel.any() else float("nan"))
    return rows, summary


def add_thesis_columns(summary: dict, thesis: dict) -> dict:
    """The thesis's printed numbers beside ours (NaN where the thesis has no such row)."""
    out = dict(summary)
    for col in ("table", "combinations", "err_x_mm", "err_y_mm", "err_z_mm"):
        out[f"thesis_{col}"] = [thesis.get((m, d), {}).get(col, float("nan"))
                                for m, d in zip(summary["method"], summary["d_mm"], strict=True)]
    return out


def format_tables(summary: dict, poses: str) -> str:
    """Our four tables in the thesis's layout, each cell ``ours (thesis)`` in mm, and the bundle's beside them."""
    _, numbers, _ = THESIS_TABLES[poses]
    lines = []
    for m in (*THESIS_METHODS, "bundle"):
        idx = {d: i for i, (d, mm) in enumerate(zip(summary["d_mm"], summary["method"], strict=True)) if mm == m}
        if not idx:
            continue
        lines.append(f"Table {numbers[m]} ({LABELS[m]}): RMS position error, ours (thesis), mm" if m in numbers else
                     f"Beside the tables ({LABELS[m]}; not in the thesis): RMS position error, mm")
        ds = sorted(idx)  # the bundle runs at some d_o only
        lines.append("d_o [mm]      " + "".join(f"{d:>14g}" for d in ds))

        def cell(i, col):
            ours, th = summary[col][i], summary[f"thesis_{col}"][i]
            if col == "combinations":
                return f"{ours:d} ({th:g})" if np.isfinite(th) else f"{ours:d}"
            mm = f"{ours:.1f}" if not abs(ours) < 1 else f"{ours:.2f}"  # the bundle's sub-mm errors
            return f"{mm} ({th:.1f})" if np.isfinite(th) else mm

        lines.append("Combinations  " + "".join(f"{cell(idx[d], 'combinations'):>14}" for d in ds))
        for ax in "xyz":
            lines.append(f"Error {ax} [mm]  " + "".join(f"{cell(idx[d], f'err_{ax}_mm'):>14}" for d in ds))
        lines.append("")
    return "\n".join(lines)


def plot_tables(summary: dict, poses: str, path) -> str:
    """Error vs intraocular distance, one panel per method (Figures 49-52 / 55-58), the thesis's values dashed; with the
    bundle a fifth panel and the efficiency (limit / error) of LMS + error ratio and the bundle."""
    plt = headless_pyplot()

    _, numbers, figs = THESIS_TABLES[poses]
    has_bundle = "bundle" in summary["method"]
    fig, axes = plt.subplots(2, 3 if has_bundle else 2, figsize=(16 if has_bundle else 11, 7.5), sharex=True)
    colors = {"x": "tab:blue", "y": "tab:orange", "z": "tab:green"}
    panels = [axes[0, 0], axes[0, 1], axes[1, 0], axes[1, 1]] + ([axes[0, 2]] if has_bundle else [])
    for ax, m in zip(panels, (*THESIS_METHODS, "bundle"), strict=False):
        sel = [i for i, mm in enumerate(summary["method"]) if mm == m]
        d = np.array(summary["d_mm"])[sel]
        for a in "xyz":
            ax.plot(d, np.array(summary[f"err_{a}_mm"])[sel], "o-", color=colors[a], ms=4, label=f"{a} (ours)")
            if m in numbers:
                ax.plot(d, np.array(summary[f"thesis_err_{a}_mm"])[sel], "s--", color=colors[a], ms=3, alpha=0.55,
                        label=f"{a} (thesis)")
            if f"bound_{a}_mm" in summary:  # the Cramér-Rao bound and the ideal estimator's Monte Carlo
                ax.plot(d, np.array(summary[f"bound_{a}_mm"])[sel], ":", color=colors[a], lw=1.6,
                        label=f"{a} limit (CRB ⊕ floor)")
                if m in numbers:
                    ax.plot(d, np.array(summary[f"bound_mc_{a}_mm"])[sel], "x", color=colors[a], ms=6,
                            label=f"{a} ideal estimator (MC)")
        if "eq123_z_mm" in summary and m in numbers:
            ax.plot(d, np.array(summary["eq123_z_mm"])[sel], "-.", color=colors["z"], lw=1, alpha=0.8,
                    label="z: Eq. 123 (disparity sqrt(2) sigma, / sqrt(inliers))")
        ax.set(yscale="log", ylabel="RMS position error (mm)")
        ax.set_title(f"Table {numbers[m]}: {LABELS[m]}" if m in numbers else
                     "not in the thesis - " + LABELS[m].replace(": ", ":\n"), fontsize=9)
        ax.grid(alpha=0.3, which="both")
    if has_bundle:  # how close each estimator comes to the limit
        ax = axes[1, 2]
        if "efficiency" in summary:
            for m, style in (("lms_ratio", "o-"), ("bundle", "s-")):
                sel = [i for i, mm in enumerate(summary["method"]) if mm == m]
                ax.plot(np.array(summary["d_mm"])[sel], np.array(summary["efficiency"])[sel], style, ms=4,
                        label=LABELS[m].split(":")[0] if m == "bundle" else "RANSAC, LMS, error ratio")
            ax.axhline(0.75, color="grey", ls="--", lw=1, label="issue 11's target 0.75")
            ax.legend(fontsize=7)
        ax.set_ylim(0, 1.1)
        ax.set_title("efficiency: limit / RMS error (3D)", fontsize=10)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("intraocular distance d_o (mm)")
    axes[0, 0].legend(fontsize=6, ncol=2)
    fig.suptitle(f"x-y table positioning error vs intraocular distance ({figs}); dashed: the thesis"
                 + ("; dotted: the limit (Cramér-Rao bound ⊕ model floor)" if "bound_x_mm" in summary else ""))
    fig.tight_layout()
    atomic_save_figure(fig, path, dpi=110)
    return Path(path).name


# ------------------------------------------------------------------------------------------------ the bound


def _bound(cfg, truth, res, pc: PositioningConfig, spec, verbose, cov_K=None, cov_dist=None) -> tuple:
    """EVALUATOR SIDE: measured feature noise, the complete Cramér-Rao bound of every estimate (the table's errors,
    the intrinsics under the pipeline's calibration covariance ``cov_K`` (4, 4) px^2 of ``fx, fy, cx, cy`` when it
    calibrated the camera, ``R0`` when it searched it, the distortion under ``cov_dist`` (4, 4) when the pipeline's
    bundle refines it under that prior), the model floor, a Monte Carlo of the ideal estimator and Eq. 123's stereo
    depth error (:mod:`bench.scenario.xy_table_bound`).

    Returns ``(metrics, columns)``: ``columns`` per intraocular distance (``d_mm`` and the bound's columns of the
    position-error table, mm and deg: ``crb_*`` the bound, ``floor_*`` the model floor, ``bound_*`` the limit, their
    root-sum-square).
    """
    from dataclasses import replace

    from bench.scenario.xy_table_bound import (
        TableKinematics,
        Unknowns,
        experiment_bounds,
        floor_positions,
        map_points,
        mc_ideal_positions,
        measured_sigma_px,
        model_poses,
    )
    from bench.vision.triangulation import stereo_sensitivity
    from bench.vision.xy_table_positioning import TableSpec, map_view_names

    p, b = cfg["pipeline"], cfg["bound"]
    ref = pc.reference
    lens, port = true_optics(truth)
    profile = imaging(cfg)
    project = true_projector(lens, port, profile)
    T_true = {n: np.array(T) for n, T in truth["T_table_cam"].items()}
    kind = "corners" if p["features"] == "corners" else "sift"
    sigma, n_sigma = measured_sigma_px(res, kind, T_true, lens, project, truth, ref, pc.map, port)
    read_err = np.array(truth["true_joints"]) - np.array(truth["read"])  # the carriage minus its reading
    metrics = {"keypoint_sigma_px": sigma, "keypoint_sigma_matches": float(n_sigma),
               "table_reading_rms_mm": float(np.sqrt(np.mean(read_err[:, :2] ** 2)) * 1e3),
               "table_reading_rms_deg": float(np.rad2deg(np.sqrt(np.mean(read_err[:, 2] ** 2))))}
    if not np.isfinite(sigma) or sigma < 1e-3:  # exact features: nothing for the pixels to bound
        return metrics, {"d_mm": []}
    kin = TableKinematics(truth, [view_name(n) for n in truth["positions"]])
    T_model = model_poses(kin)
    metrics["bound_pose_check_mm"] = float(max(np.abs(T_model[n][:3, 3] - T_true[n][:3, 3]).max()
                                               for n in T_true) * 1e3)  # the bound's table model = the simulator's
    names = list(res.observations)
    centres = np.stack([res.T_table_cam[n][:3, 3] for n in names])
    X, seen = map_points(res, ref, T_model[ref], map_view_names(names, centres, ref, (), pc.map_min_baseline_m,
                                                                  pc.map_exclude))
    unknowns = Unknowns(lens.K, cov_K, R0_free=p["mount_bias"] == "estimated", cov_dist=cov_dist,
                        offset_sigma=spec.camera_offset_sigma_m)
    bounds = experiment_bounds(res, kin, pc, X, seen, project, lens.size, sigma, verbose, unknowns)
    metrics.update({"bound_intrinsics_free": float(cov_K is not None), "bound_R0_free": float(unknowns.R0_free),
                    "bound_distortion_free": float(cov_dist is not None),
                    "bound_centre_free": float(unknowns.offset_sigma is not None)})
    cols = {k: [] for k in ("d_mm", "bound_x_mm", "bound_y_mm", "bound_z_mm", "bound_pos_mm", "bound_rot_deg",
                            "crb_x_mm", "crb_y_mm", "crb_z_mm", "crb_pos_mm", "floor_x_mm", "floor_y_mm",
                            "floor_z_mm", "floor_pos_mm", "bound_mc_x_mm", "bound_mc_y_mm", "bound_mc_z_mm",
                            "bound_mc_pos_mm", "eq123_z_mm")}
    # the model floor: the estimator on noise-free features through the true optics, exact table, R0 and centre
    T_mc = np.array(truth["T_mount_cam"])
    spec_true = TableSpec(np.array(truth["camera_offset_m"]) + T_mc[:3, 3], spec.travel_m, spec.resolution_m,
                          spec.resolution_rad)
    floor, floor_fails, misfit = floor_positions(kin, X, seen, lens, port, profile, spec_true, T_mc[:3, :3],
                                                 replace(pc, methods=("lms_ratio",)))
    metrics["floor_failures"] = float(floor_fails)
    metrics["floor_misfit_px"] = misfit
    # the Monte Carlo: the thesis's estimator (LMS + error ratio) on ideal features, true lens, R0 and centre
    mc = {}
    d_mc = [float(d) for d in b["mc_intraocular_mm"] if float(d) in res.pairs]
    if b["mc_trials"] > 0 and d_mc:
        mc = mc_ideal_positions(kin, X, seen, lens, spec_true, T_mc[:3, :3],
                                replace(pc, methods=("lms_ratio",), intraocular_mm=tuple(d_mc)), sigma,
                                np.random.default_rng([cfg["seed"], 17]), b["mc_trials"],
                                table_errors=bool(cfg["sim"]["table_errors"]))
        metrics["bound_mc_failures"] = float(mc.pop("failures"))
    z_ref = float(np.median(transform_points(invert(T_model[ref]), X)[:, 2]))
    K = lens.K
    for d in sorted(res.pairs):
        got = [v for (dd, _, _), v in bounds.items() if dd == d]
        if not got:
            continue
        var = np.mean([np.diag(v["cov_pos"]) for v in got], axis=0)
        f = floor.get(round(d, 6))
        fl = np.sqrt(np.mean(f**2, axis=0)) if f is not None and len(f) else np.full(3, np.nan)  # RMS over pairs
        cols["d_mm"].append(float(d))
        for i, ax in enumerate("xyz"):
            cols[f"crb_{ax}_mm"].append(float(np.sqrt(var[i]) * 1e3))
            cols[f"floor_{ax}_mm"].append(float(fl[i] * 1e3))
            cols[f"bound_{ax}_mm"].append(float(np.sqrt(var[i] + fl[i] ** 2) * 1e3))  # NaN: the floor failed
        cols["crb_pos_mm"].append(float(np.sqrt(var.sum()) * 1e3))
        cols["floor_pos_mm"].append(float(np.sqrt(np.sum(fl**2)) * 1e3))
        cols["bound_pos_mm"].append(float(np.sqrt(var.sum() + np.sum(fl**2)) * 1e3))
        cols["bound_rot_deg"].append(float(np.rad2deg(np.sqrt(np.mean([np.trace(v["cov_rot"]) for v in got])))))
        e = mc.get(round(d, 6))
        rms = np.sqrt(np.mean(e**2, axis=0)) * 1e3 if e is not None and len(e) else np.full(3, np.nan)
        for i, ax in enumerate("xyz"):
            cols[f"bound_mc_{ax}_mm"].append(float(rms[i]))
        cols["bound_mc_pos_mm"].append(float(np.sqrt(np.sum(rms**2))))
        # Eq. 123: depth error of one point for a disparity error sqrt(2) sigma, averaged over the pair's inliers
        n_in = [c.inliers for c in res.combinations if c.success and c.method == "lms_ratio" and
                abs(c.d_m * 1e3 - d) < 1e-6]
        dz = stereo_sensitivity(K[0, 2], K[1, 2], K[0, 2], K[1, 2], K[0, 0], K[1, 1], d * 1e-3, z_ref,
                                np.sqrt(2) * sigma)[2]
        cols["eq123_z_mm"].append(float(abs(dz) / np.sqrt(np.median(n_in)) * 1e3) if n_in else float("nan"))
    metrics["bound_points"] = float(len(X))
    metrics["bound_observations_median"] = float(np.median([v["observations"] for v in bounds.values()]))
    return metrics, cols


# ------------------------------------------------------------------------------------------------ run


def _aligned(feats, images, ref, cfg: MapConfig) -> dict:
    """``pipeline.keypoints: aligned`` - every view's keypoints matched to the reference view's moved onto its
    patches (:func:`bench.vision.patch_align.align_to_reference`, matched as the experiment's map ``cfg``)."""
    from bench.vision.insitu import view_matches
    from bench.vision.patch_align import align_to_reference, grey

    if ref not in feats:
        return feats
    others = {n: (grey(images[n]), f) for n, f in feats.items() if n != ref}
    out, _, _ = align_to_reference(grey(images[ref]), feats[ref], others, lambda a, b: view_matches(a, b, cfg))
    return {ref: feats[ref], **out}


def run(cfg, out_dir, verbose=True):
    """Render (cached), calibrate the camera, run the positioning pipeline, score against the truth."""
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    s, p = cfg["sim"], cfg["pipeline"]
    ds_dir = out_dir / "dataset"
    cache = out_dir.parent / ".render_cache" if cfg["outputs"]["cache"] else None
    checks = render(cfg, ds_dir, verbose=verbose, cache_dir=cache)
    timings = {"render_s": time.perf_counter() - t0}
    ds = load_dataset(ds_dir)
    truth = yaml.safe_load((ds_dir / "truth" / "truth.yaml").read_text())  # the evaluator's business only
    injected = []
    metrics = dict(checks)

    # --- the camera -------------------------------------------------------------------------------------------------
    t1 = time.perf_counter()
    K_true = np.array(truth["camera_K"])
    cov_K = None  # the calibration's covariance of fx, fy, cx, cy (px^2): the complete bound's intrinsics prior
    if p["camera"] == "calibrated":
        cal, n_cal, cov_K = calibrate_from_rig_views(ds, p["camera_model"], extractor=p["calibration_corner_extractor"])
        camera = cal.camera
        metrics.update({"calibration_fx_std_px": float(np.sqrt(cov_K[0, 0])), "reproj_rms_px": float(cal.rms_px),
                        "calibration_views_used": float(n_cal)})
    elif p["camera"] == "nominal":
        camera = ds.camera()
    else:
        injected.append("camera")
        camera = CameraModel(int(truth["camera_size"][0]), int(truth["camera_size"][1]), K_true,
                             np.array(truth["camera_dist"]), name="true lens (INJECTED)")
    metrics["focal_err_pct"] = float(abs(camera.K[0, 0] / K_true[0, 0] - 1) * 100)
    metrics["eq199_baseline_mm"] = float(required_baseline(p["range_mm"] * 1e-3, camera.K[0, 0],
                                                           p["depth_resolution_mm"] * 1e-3) * 1e3)
    timings["camera_s"] = time.perf_counter() - t1

    # --- features ---------------------------------------------------------------------------------------------------
    t1 = time.perf_counter()
    views = table_views(ds)
    names = [v.name for v in views]
    map_cfg = MapConfig(orientation_tol_deg=p["orientation_tol_deg"], gap_max_m=p["gap_mm"] * 1e-3)
    if p["features"] == "true_projection":
        injected.append("features")
        reference = replay_reference_object(cfg, truth) if s["reference_object"] == "robot" else None
        if s["reference_object"] == "robot" and reference is None:
            raise ConfigError(ds.root, "truth/truth.yaml", "pipeline.features=true_projection: the desk robot could "
                                                           "not be replayed from the seed (a dataset rendered by "
                                                           "another version or seed)")
        feats = true_projection_features(truth, names, s["true_projection_points"],
                                         np.random.default_rng((cfg["seed"], 7)), imaging(cfg), reference)
    elif p["features"] == "sift":
        images = {v.name: v.image(expected_size=camera.size) for v in views}
        feats = {n: detect_sift(img, channel_order="rgb") for n, img in images.items()}
        if p["keypoints"] == "aligned":
            feats = _aligned(feats, images, view_name(p["reference_view"]), map_cfg)
    else:
        geometry = load_target(ds.root / "target.yaml")
        feats, lost = {}, []
        for v in views:
            f, _ = rig_corner_features(v.image(expected_size=camera.size), geometry, p["corner_extractor"])
            if f is not None:
                feats[v.name] = f
            else:
                lost.append(v.name)
        metrics["corner_views_lost"] = float(len(lost))
    timings["features_s"] = time.perf_counter() - t1
    ref = view_name(p["reference_view"])
    if ref not in feats:
        raise ConfigError(ds_dir, ref, "no features found in the reference view")

    # --- the mount bias and the experiment --------------------------------------------------------------------------
    R0_true = np.array(truth["T_mount_cam"])[:3, :3]
    R0 = None
    if p["mount_bias"] == "truth":
        injected.append("mount_bias")
        R0 = R0_true
    elif p["mount_bias"] == "zero":
        R0 = np.eye(3)
    pc = PositioningConfig(
        reference=ref, intraocular_mm=tuple(float(d) for d in p["intraocular_mm"]),
        map_min_baseline_m=p["map_min_baseline_mm"] * 1e-3,
        map_exclude=tuple(view_name(n) for n in cfg["pipeline"]["map_exclude"]),
        map=map_cfg,
        ransac_iterations=p["ransac_iterations"], d_r_m=p["d_r_mm"] * 1e-3, r_lim=p["r_lim"],
        bias_refine=p["bias_refine"], bias_depth_statistic=p["bias_depth_statistic"], seed=cfg["seed"],
        methods=THESIS_METHODS + (("bundle",) if p["bundle"] else ()),
        bundle_intraocular_mm=tuple(float(d) for d in p["bundle_intraocular_mm"]), bundle_readings=p["bundle_readings"],
        bundle_centre=p["bundle_centre"])
    sd = p["bundle_distortion_sigma"]
    cov_dist = np.diag(np.square(np.asarray(sd, float))) if sd else None  # [] keeps the camera's distortion fixed
    spec = load_table_spec(ds.root / "table.yaml")
    res = estimate_positions(feats, {n: ds.view(n).table for n in feats}, camera, spec, pc, R0=R0, verbose=verbose,
                             cov_K=cov_K, cov_dist=cov_dist)
    timings.update({k: float(v) for k, v in res.timings_s.items()})

    # --- score ------------------------------------------------------------------------------------------------------
    rows, summary = score(res, truth, ref, pc.methods)
    thesis = load_thesis_table(s["poses"])
    summary = add_thesis_columns(summary, thesis)
    b_true = np.array(truth["mount_bias_deg"])
    metrics["bias_rot_err_deg"] = float(np.rad2deg(rotation_angle(res.R0.T @ R0_true)))
    for i, a in enumerate(("x0", "y0", "z0")):
        metrics[f"theta_{a}_true_deg"] = float(b_true[i])
        if np.isfinite(res.bias_deg[i]):
            metrics[f"theta_{a}_deg"] = float(res.bias_deg[i])
            metrics[f"theta_{a}_err_deg"] = float(res.bias_deg[i] - b_true[i])
    metrics["truth_injected"] = float(len(injected))
    metrics["combinations_total"] = float(sum(len(v) for v in res.pairs.values()))
    metrics["estimates_failed"] = float(sum(not c.success for c in res.combinations))
    metrics["keypoints_median"] = float(np.median(list(res.keypoints.values())))
    metrics["keypoints_reference"] = float(res.keypoints[ref])
    ok = [c for c in res.combinations if c.success and c.method != "bundle"]  # the thesis's map and inlier counts
    if ok:
        metrics.update({f"{k}_median": float(np.median([getattr(c, k) for c in ok]))
                        for k in ("map_points", "pairs_3d", "inliers")})
    if cfg["bound"]["enabled"] and res.success:
        t1 = time.perf_counter()
        bound_metrics, columns = _bound(cfg, truth, res, pc, spec, verbose, cov_K,
                                        cov_dist if "bundle" in pc.methods else None)
        metrics.update(bound_metrics)
        by_d = {round(d, 6): i for i, d in enumerate(columns.pop("d_mm"))}
        for col, vals in columns.items():
            summary[col] = [vals[by_d[round(d, 6)]] if round(d, 6) in by_d else float("nan") for d in summary["d_mm"]]
        if "bound_pos_mm" in summary:  # efficiency = bound / achieved, per d_o and method
            summary["efficiency"] = [b / e if e > 0 else float("nan")
                                     for b, e in zip(summary["bound_pos_mm"], summary["err_pos_mm"], strict=True)]
        timings["bound_s"] = time.perf_counter() - t1
    ds_list = sorted(res.pairs)
    for m in pc.methods:
        # per-axis errors at 100, 50 mm and the extreme d_o (all methods); for LMS + error ratio the 3D error at
        # every d_o, and the bound named to pair with the error it bounds (x_err_y / x_bound_y: sweeps put the
        # efficiency RMS bound / RMS error beside them); for the bundle its efficiency at 100 and 50 mm
        labels = [(100.0, "100"), (50.0, "50"), (ds_list[0], "min_d"), (ds_list[-1], "max_d")]
        if m == "lms_ratio":
            labels += [(d, f"{d:g}") for d in ds_list if d not in (100.0, 50.0)]
        for d_key, label in labels:
            idx = [i for i, (d, mm) in enumerate(zip(summary["d_mm"], summary["method"], strict=True))
                   if mm == m and abs(d - d_key) < 1e-6]
            if not idx:
                continue
            i = idx[0]
            metrics[f"{m}_err_pos_at_{label}_mm"] = summary["err_pos_mm"][i]
            if label in ("100", "50", "min_d", "max_d"):
                for ax in "xyz":
                    metrics[f"{m}_err_{ax}_mm_at_{label}"] = summary[f"err_{ax}_mm"][i]
            if "bound_pos_mm" not in summary or label in ("min_d", "max_d"):
                continue
            if m == "bundle" and label in ("100", "50"):  # the same limit as LMS + error ratio: its efficiency
                metrics[f"{m}_efficiency_at_{label}"] = summary["efficiency"][i]
            if m != "lms_ratio":
                continue
            metrics[f"{m}_bound_pos_at_{label}_mm"] = summary["bound_pos_mm"][i]
            if label in ("100", "50"):
                for ax in "xyz":
                    for col in ("bound", "crb", "floor"):
                        metrics[f"{m}_{col}_{ax}_mm_at_{label}"] = summary[f"{col}_{ax}_mm"][i]
                metrics[f"{m}_bound_mc_pos_at_{label}_mm"] = summary["bound_mc_pos_mm"][i]
                metrics[f"{m}_efficiency_at_{label}"] = summary["efficiency"][i]
                metrics[f"bound_rot_at_{label}_deg"] = summary["bound_rot_deg"][i]
    timings["total_s"] = time.perf_counter() - t0

    # --- outputs ----------------------------------------------------------------------------------------------------
    setup = {"item": ["camera", "mount_bias", "features", "table_errors", "port", "sensor_noise", "optics",
                      "reference_object", "camera_model"],
             "value": [p["camera"], p["mount_bias"], p["features"], str(s["table_errors"]), str(s["port"]),
                       str(s["sensor_noise"]), s["optics"], s["reference_object"], p["camera_model"]],
             "truth_injected": [int(k in injected) for k in ("camera", "mount_bias", "features")] + [0] * 6}
    write_table_csv(out_dir / "position_error_vs_intraocular.csv", summary)
    write_table_csv(out_dir / "combinations.csv", rows)
    write_table_csv(out_dir / "setup.csv", setup)
    artifacts = {"dataset": "dataset", "table": "position_error_vs_intraocular.csv", "combinations": "combinations.csv",
                 "setup": "setup.csv"}
    if cfg["outputs"]["plots"] and summary["d_mm"]:
        artifacts["plot"] = plot_tables(summary, s["poses"], out_dir / "position_error_vs_intraocular.png")
    if cfg["outputs"]["rerun"]:
        from bench.scenario.xy_table_recording import record_xy_table

        record_xy_table(out_dir / "recording.rrd", cfg, ds, truth, res, camera, summary, metrics)
        artifacts["recording"] = "recording.rrd"
    path = write_result(out_dir, cfg["name"], cfg["seed"], metrics,
                        {"position_error_vs_intraocular": summary, "combinations": rows, "setup": setup}, timings,
                        artifacts)
    if verbose:
        print(f"{cfg['name']} (seed {cfg['seed']}): {res.message}")
        if injected:
            print(f"  TRUTH INJECTED (evaluator side): {', '.join(injected)}")
        if res.search is not None:
            print(f"  mount rotation search: {res.search.message}; true theta_x0, y0, z0 = {b_true.tolist()} deg")
        print(format_tables(summary, s["poses"]))
        for k in ("lms_ratio_err_x_mm_at_100", "lms_ratio_err_y_mm_at_100", "lms_ratio_err_z_mm_at_100",
                  "bias_rot_err_deg", "reproj_rms_px", "focal_err_pct", "keypoints_reference", "map_points_median",
                  "inliers_median", "estimates_failed"):
            if k in metrics:
                print(f"  {k:<28} {metrics[k]:.4g}")
        print("  timings: " + ", ".join(f"{k} {v:.1f}" for k, v in timings.items() if v >= 0.05))
    return path
