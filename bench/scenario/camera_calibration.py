"""Scenario kind ``camera_calibration``: the thesis's camera calibrations (Tables 3, 9 and 15) on rendered rig views.

The thesis calibrated two cameras with the two-plane rig of section 5.2 (two perpendicular 7 x 7-square boards):

* the Logitech webcam (section 5.2.1): seven photos, each calibrated alone with the pin-hole model - DLT (Eq. 55-58),
  decomposition (Eq. 59-66), the error chi of Eq. 195-196 - giving Table 3, whose average became the camera's K;
* the underwater MCH-3000P camera with Heikkilä's model (section 3.3.2, Eq. 74-76, Levenberg-Marquardt) in air
  (section 5.3, Table 9) and submerged in a water tank (section 5.5, Table 15).

``camera.preset: air_webcam`` reproduces the first, ``camera.preset: underwater`` with ``camera.medium: air | water |
both`` the second. The simulation (``render``, also ``bench sim render``) writes one dataset per medium, as a real
campaign would: the rig views (PNG), ``table.csv`` (the x-y table's readings: the thesis photographed the rig with
the camera on the table of section 5.2), ``target.yaml`` (the rig's nominal geometry), the *nominal* ``camera.yaml``
(the thesis's calibration: Table 3's average, Table 9 or Table 15) and ``truth/`` (the true camera, the port, the
true pose of the rig in the camera frame for every view).

The true camera is the nominal lens perturbed (``truth.focal_error_pct``, ``truth.principal_error_px``,
``truth.distortion_error_pct``: uniform draws from the seed). Under water the simulator renders that same lens
(Table 9's, perturbed) behind the housing's flat port in water (:mod:`bench.sim.optics_presets`), while the pipeline
is given Table 15 as its nominal camera; with ``camera.medium: both`` the air and water campaigns share the true
lens (one physical camera, calibrated twice). In air the underwater camera sits in its housing too (the glass slab
of ``underwater_in_air``) unless ``camera.housing: false``.

Views: the rig stands ``rig.distance_mm`` in front of the table's centre (``rig.distance_water_mm`` under water, where
the port magnifies by ~1.34), its fold vertical and its bisector towards the camera. For view k the table moves the
camera by a random ``z`` within ``views.depth_range_mm`` (and a few mm in ``x``) and turns it so that the rig appears
towards one of the image's corners or edges (centre first, then the corners, then the edge midpoints), ``views.spread``
of the free room away from the centre; the rig is raised or lowered for the vertical placement and turned about its
fold by up to ``rig.yaw_deg``. A view whose rig would leave the image is pulled back towards the centre; if even the
centred rig does not fit, a one-line error names the view.

The pipeline (``run``) uses only the public part of each dataset: corners by the thesis's extractor (non-maximum
suppression + k-means lines, section 3.3.3-3.3.5) or OpenCV's (``pipeline.extractor``), then

* Table 3: each view calibrated alone with the pin-hole model (:func:`bench.camera.calibration.per_view_pinhole`),
  printed beside the thesis's Table 3 (``scenarios/data/table3_thesis.csv``) with the average row, and Figure 44
  (the residual vectors of view 1 magnified 50 times);
* the multi-view calibration with ``pipeline.model`` (Heikkilä by default: k1, k2, p1, p2, LM over all views) and
  OpenCV's ``calibrateCamera`` on the same detections; for the underwater camera its parameters in the thesis's units
  (s_u, f, u0, v0, k1, k2, T1, T2: :mod:`bench.camera.heikkila`) beside Table 9 or 15, with standard errors, and
  Figure 53/59 (the extracted corners and their corrected positions).

Scoring (the evaluator reads ``truth/``): ``corner_rms_px`` (extracted corners vs the true projections of the rig's
corners, each extraction matched to its nearest true corner), ``focal_err_pct`` (the larger of the fx, fy errors;
in water against the port's paraxial effective focal length ``n_water / n_air`` times the lens's, as the in-situ
scenario does), the errors of every parameter with their standard errors and how many of the Heikkilä coefficients
lie within 1, 2, 3 standard errors of the truth (in air; under water there is no true Heikkilä camera: the flat port
is not a single-viewpoint camera), and the *oracle*: the same model fitted to the exact projections of the same
corners. The oracle's RMS (``model_floor_rms_px``) is the error of the model itself - ~1e-10 px for a lens in air
without housing, the refraction of the slab or port otherwise - and its parameters are what a perfect extractor
would give (``oracle_within_*``: the pipeline's estimate against them).

``result.json`` metrics (names are a contract): ``reproj_rms_px``, ``focal_err_pct``, ``opencv_reproj_rms_px``,
``corner_rms_px``, ``err_<p>`` / ``std_<p>`` for ``fx_px, fy_px, cx_px, cy_px, k1, k2, p1, p2`` and (underwater
camera) ``s_u, f_px, u0_px, v0_px, k1_per_mm2, k2_per_mm4, T1_per_mm, T2_per_mm``, ``heikkila_within_{1,2,3}std``,
``heikkila_max_abs_z``, ``oracle_within_{1,2,3}std``, ``model_floor_rms_px``; Table 3 figures for the webcam. With
``camera.medium: both`` every metric and table is written with the prefixes ``air_`` and ``water_``, and the
unprefixed names hold the in-water calibration (section 5.5: the camera as it goes subsea).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import Field, model_validator

from bench.camera import dlt
from bench.camera.calibrate_dataset import detect_dataset_corners, load_target_tolerance
from bench.camera.calibration import calibrate_camera, jackknife_views, opencv_reference, per_view_pinhole
from bench.camera.flatport import FlatPort, lens_port_projector
from bench.camera.heikkila import OPENCV_NAMES, heikkila_covariance, opencv_to_heikkila
from bench.camera.io import camera_yaml_text, thesis_blocks, write_camera_yaml
from bench.camera.model import CameraModel, to_pixels
from bench.camera.plots import plot_residual_vectors
from bench.camera.presets import load_preset
from bench.camera.target_tolerance import calibration_with_tolerance
from bench.config import ImagingParams, KeyProblem, PositiveInt, RenderOutputs, ScenarioBase, Section, section
from bench.dataset import DatasetWriter, load_dataset
from bench.errors import ConfigError
from bench.fileio import atomic_write_text, csv_number, read_csv_table
from bench.geometry.transforms import homogeneous, invert, rot_z, transform_points
from bench.scenario.results import write_result, write_table_csv
from bench.sim.campaign import CachedCamera
from bench.sim.imaging import draw_true_lens, profile_from_config, rig_errors, rig_target_yaml

MAGNITUDE_PCT = Annotated[float, Field(ge=0, le=50)]
MEDIA = {"air": ("air",), "water": ("water",), "both": ("air", "water")}


class Camera(Section):
    preset: Literal["air_webcam", "underwater"] = "air_webcam"
    medium: Literal["air", "water", "both"] = "air"
    supersample: Annotated[int, Field(ge=1, le=16)] = 3
    housing: bool = True
    imaging: str = "realistic"
    imaging_off: list[str] = []
    imaging_params: ImagingParams = {}

    @model_validator(mode="after")
    def _media(self):
        if self.preset == "air_webcam" and self.medium != "air":
            raise KeyProblem("medium", "the webcam (air_webcam) is calibrated in air only")
        if "water" in MEDIA[self.medium] and not self.housing:
            raise KeyProblem("housing", "the camera cannot be submerged without its housing")
        return self


class Truth(Section):
    focal_error_pct: MAGNITUDE_PCT = 1.5
    principal_error_px: Annotated[float, Field(ge=0, le=100)] = 4.0
    distortion_error_pct: MAGNITUDE_PCT = 10.0
    table_errors: bool = True


class Rig(Section):
    distance_mm: Annotated[float, Field(ge=300, le=5000)] = 1000.0
    distance_water_mm: Annotated[float, Field(ge=300, le=5000)] = 1000.0
    yaw_deg: Annotated[float, Field(ge=0, le=30)] = 10.0
    margin_px: Annotated[float, Field(ge=0, le=100)] = 8.0


class Views(Section):
    count: PositiveInt = 7  # the rig is non-planar: one view calibrates
    spread: Annotated[float, Field(ge=0, le=1)] = 0.8
    depth_range_mm: Annotated[float, Field(ge=0, le=100)] = 100.0  # the table's z travel is +-100 mm


class Pipeline(Section):
    extractor: Literal["thesis", "opencv"] = "thesis"
    model: Literal["heikkila", "radial", "pinhole"] = "heikkila"
    refine_corners: bool = True
    compare_extractors: bool = True
    table3_edges: Literal["pixel", "subpixel"] = "pixel"
    target_tolerance: bool = True
    tolerance_draws: Annotated[int, Field(ge=10, le=1000)] = 48


class Scenario(ScenarioBase):
    """A ``camera_calibration`` scenario file."""

    camera: Camera = section(Camera)
    truth: Truth = section(Truth)
    rig: Rig = section(Rig)
    views: Views = section(Views)
    pipeline: Pipeline = section(Pipeline)
    outputs: RenderOutputs = section(RenderOutputs)


#: (camera.preset, medium) -> optics preset of bench.sim.optics_presets
OPTICS = {("air_webcam", "air"): "air_webcam", ("underwater", "air"): "underwater_in_air",
          ("underwater", "water"): "underwater_in_water"}
TABLE3_CSV = Path(__file__).resolve().parents[2] / "scenarios" / "data" / "table3_thesis.csv"
TABLE3_COLUMNS = ("picture", "theta_deg", "alpha_px", "beta_px", "u0_px", "v0_px", "chi_px")
#: the Heikkilä parameters in the thesis's units (Tables 9 and 15) and the factor from SI
HEIKKILA_ROWS = (("s_u", "s_u", 1.0), ("f_px", "f", None), ("u0_px", "u0", 1.0), ("v0_px", "v0", 1.0),
                 ("k1_per_mm2", "k1", 1e-6), ("k2_per_mm4", "k2", 1e-12), ("T1_per_mm", "p1", 1e-3),
                 ("T2_per_mm", "p2", 1e-3))
OPENCV_ROWS = ("fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2")
_CV_KEY = {"fx": "fx_px", "fy": "fy_px", "cx": "cx_px", "cy": "cy_px"}
#: image placements of the rig, in units of the free room: centre, the four corners, the four edge midpoints
PLACEMENTS = ((0, 0), (-1, -1), (1, 1), (1, -1), (-1, 1), (0, -1), (0, 1), (-1, 0), (1, 0))


# ------------------------------------------------------------------------------------------------ configuration


def imaging(cfg):
    """The scenario's imaging profile (``camera.imaging``, ``camera.imaging_off``: :mod:`bench.sim.imaging`)."""
    return profile_from_config(cfg, "camera")


def validate(cfg) -> None:
    """The check the model cannot make (the imaging profile, :mod:`bench.sim.imaging`), run by ``load_scenario``
    before anything is created or rendered (also by sweeps)."""
    imaging(cfg)


def media(cfg) -> tuple:
    """The media of the scenario, ``("air",)``, ``("water",)`` or ``("air", "water")``."""
    return MEDIA[cfg["camera"]["medium"]]


def dataset_dirs(cfg, root) -> dict:
    """``{medium: dataset folder}``: ``root`` itself for one medium, ``root/in_air`` and ``root/in_water`` for both."""
    root = Path(root)
    ms = media(cfg)
    return {m: root if len(ms) == 1 else root / f"in_{m}" for m in ms}


def _optics(cfg, medium):
    from bench.sim.optics_presets import optics_preset

    name = OPTICS[(cfg["camera"]["preset"], medium)]
    return optics_preset(name, overrides=None if cfg["camera"]["housing"] else {"port": None})


# ------------------------------------------------------------------------------------------------ simulation


class TableRigScene(CachedCamera):
    """The camera on the x-y table photographing the two-plane rig, through the optics of a preset.

    One MuJoCo model: the table of :func:`bench.sim.scenes.xy_table.xy_table` with the camera in its mount body and
    the rig as a mocap body (its pose set per view). The views are rendered through the optics chain of
    :class:`bench.sim.campaign.CachedCamera` (supersampled pinhole render -> lens stage or lens + flat port -> medium
    and sensor, as the x-y table scenario's camera and the arm's), cached on disk by a content hash of the model, the
    optics, the table joints, the rig pose and the noise seed, so a sweep never renders a view twice.

    Parameters
    ----------
    camera : CameraModel
        The TRUE lens camera (inside the housing when ``optics.port`` is set).
    optics : OpticsPreset
        Port (or None) and the medium/sensor chain.
    table_model : TableModel
    rig : SceneObject
        :func:`~bench.sim.scenes.rig.calibration_rig`.
    supersample : int
    cache_dir : path or None
    z_min : float
        Nearest scene depth the flat-port render must cover (m).
    """

    CAMERA = "table_camera"

    def __init__(self, camera: CameraModel, optics, table_model, rig, supersample: int, cache_dir=None,
                 z_min: float = 0.3, imaging=None):
        from bench.sim.camera import add_opencv_camera
        from bench.sim.scenes.base import compose, place
        from bench.sim.scenes.xy_table import xy_table

        super().__init__(camera, supersample, optics.port, z_min)
        spec = self.spec
        table = xy_table(table_model, lambda body: add_opencv_camera(body, self.CAMERA, spec.K, spec.width,
                                                                     spec.height, np.eye(4)))
        self.T_world_table = table.features["T_world_table"]
        rig_body = place(rig, np.eye(4), f"{rig.name}_mocap", mocap=True)
        self._start_cache(compose([table, rig_body], offscreen=(spec.width, spec.height),
                                  center=self.T_world_table[:3, 3], extent=3.0).compile(), optics.chain, imaging,
                          cache_dir)
        self._mocap = self.model.body_mocapid[self.model.body(f"{rig.name}_mocap").id]
        self._qadr = {n: self.model.jnt_qposadr[self.model.joint(n).id] for n in table_model.joint_names}

    def _set_state(self, qpos: dict, T_world_rig):
        from bench.geometry.quaternion import matrix_to_quaternion

        def set_state(model, data):
            for name, adr in self._qadr.items():
                data.qpos[adr] = qpos[name]
            data.mocap_pos[self._mocap] = T_world_rig[:3, 3]
            data.mocap_quat[self._mocap] = matrix_to_quaternion(T_world_rig[:3, :3])
        return set_state

    def pose(self, qpos: dict, T_world_rig):
        """Set the table joints (``TableRun.qpos`` of one view) and the rig pose; returns the true ``T_world_cam``."""
        import mujoco

        from bench.sim.camera import camera_pose_cv

        self._set_state(qpos, T_world_rig)(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        return camera_pose_cv(self.model, self.data, self.CAMERA)

    def render(self, qpos: dict, T_world_rig, seed: int):
        """``(image uint8 (H, W, 3), T_world_cam (4, 4))`` of one view (from the cache when rendered before)."""
        T_world_cam = self.pose(qpos, T_world_rig)
        key = np.concatenate([[qpos[n] for n in sorted(qpos)], np.ravel(T_world_rig)])
        return self._render(self.CAMERA, self._set_state(qpos, T_world_rig), key, seed), T_world_cam


def _pattern_outline(rig, samples: int = 12) -> np.ndarray:
    """Points ``(M, 3)`` (rig frame, m) along the outer edges of both printed patterns (what must stay in view)."""
    f = rig.features
    s = f["square_m"]
    n = f["pattern_size"][0] + 1  # squares per side
    t = np.linspace(0.0, 1.0, samples)
    out = []
    for T in (f["T_rig_board_a"], f["T_rig_board_b"]):
        c = np.array([[0, 0], [n * s, 0], [n * s, n * s], [0, n * s], [0, 0]], float)
        for a, b in zip(c[:-1], c[1:], strict=True):
            xy = a + t[:, None] * (b - a)
            out.append(transform_points(T, np.c_[xy, np.zeros(len(xy))]))
    return np.vstack(out)


def _rig_pose(T_table_rig0, centroid, height_m, yaw):
    """Rig pose in the table frame: the base pose turned by ``yaw`` about the fold direction through the corners'
    centroid, then moved ``height_m`` along the table's y (down)."""
    turn = homogeneous(rot_z(yaw), centroid - rot_z(yaw) @ centroid)
    return homogeneous(np.eye(3), [0.0, height_m, 0.0]) @ T_table_rig0 @ turn


def plan_views(cfg, medium, camera: CameraModel, port, table_model, rig, rng):
    """Table commands, rig poses and true camera poses of the views (module docstring).

    Returns ``(commands (n, 3) [x_m, z_m, rot_rad], rig (n, 2) [height_m, yaw_rad], T_table_rig (n, 4, 4))``.
    The rig must be seen whole with ``rig.margin_px`` to spare; a view where it is not is pulled back towards the
    centre (halving its offset); when even the centred rig leaves the image, a one-line ConfigError names the view.
    """
    from bench.sim.scenes.xy_table import reference_pose

    src = cfg["_file"]
    v = cfg["views"]
    dist_key = "rig.distance_mm" if medium == "air" else "rig.distance_water_mm"
    distance = cfg["rig"][dist_key.split(".")[1]] * 1e-3
    T0 = reference_pose(rig, distance)
    corners = rig.features["corners"]
    centroid = corners.mean(axis=0)
    outline = _pattern_outline(rig)
    margin = cfg["rig"]["margin_px"]
    W, H = camera.size
    mag = 1.0 if port is None else port.n_water / port.n_air
    fx, fy = mag * camera.fx, mag * camera.fy
    c_tab = transform_points(T0, outline)  # extent of the rig around its centre, table frame
    ctr = transform_points(T0, centroid)
    ext = np.abs(c_tab - ctr).max(axis=0)
    commands, rig_params, poses = [], [], []
    for k in range(v["count"]):
        a = np.array(PLACEMENTS[k % len(PLACEMENTS)], float)
        a = np.clip(a + rng.uniform(-0.15, 0.15, 2), -1, 1)
        z_cmd = rng.uniform(-1, 1) * v["depth_range_mm"] * 1e-3
        x_cmd = rng.uniform(-1, 1) * 0.02
        yaw = rng.uniform(-1, 1) * np.deg2rad(cfg["rig"]["yaw_deg"])
        D = ctr[2] - z_cmd
        room = np.array([W / 2 - margin - fx * ext[0] / D, H / 2 - margin - fy * ext[1] / D])
        offset = a * v["spread"] * np.maximum(room, 0.0)  # px from the image centre
        for attempt in range(8):
            height = offset[1] * D / fy
            T_tr = _rig_pose(T0, centroid, height, yaw)
            bearing = np.arctan2(ctr[0] - x_cmd, D)
            rot = bearing - np.arctan2(offset[0], fx)  # the camera turns about y (down) by rot
            cmd = np.array([x_cmd, z_cmd, rot])
            run = table_model.run(cmd[None])
            T_table_cam = run.T_table_mount[0]
            p_cam = transform_points(invert(T_table_cam) @ T_tr, outline)
            uv = lens_port_projector(camera, port)(p_cam)  # the true pixels: lens alone, or port then lens
            ok = np.all(np.isfinite(uv)) and camera.in_image(uv, border=margin).all()
            if ok:
                break
            if attempt == 7 or not np.any(offset):
                raise ConfigError(src, f"view {k + 1}", f"the rig leaves the image even centred ({dist_key} = "
                                  f"{distance * 1e3:g} mm is too close for this camera, or rig.margin_px too large)")
            offset = offset * 0.5 if attempt < 6 else np.zeros(2)
        commands.append(cmd)
        rig_params.append([height, yaw])
        poses.append(T_tr)
    return np.array(commands), np.array(rig_params), np.array(poses)


def _render_medium(cfg, medium, true_lens, rng, out_dataset, cache_dir, verbose, seed_offset):
    """Render one medium's campaign and write its dataset; returns the simulator checks."""
    from bench.sim.scenes.rig import calibration_rig
    from bench.sim.scenes.xy_table import lab_table_model, random_table_errors

    t0 = time.perf_counter()
    optics = _optics(cfg, medium)
    nominal = load_preset(optics.nominal_camera)
    errors = random_table_errors(rng) if cfg["truth"]["table_errors"] else None
    table_model = lab_table_model(errors)
    profile = imaging(cfg)
    target = rig_errors(profile, cfg["seed"])  # one physical rig per seed
    rig = calibration_rig(name="rig", errors=target)
    commands, rig_params, T_table_rig = plan_views(cfg, medium, true_lens, optics.port, table_model, rig, rng)
    run = table_model.run(commands)
    scene = TableRigScene(true_lens, optics, table_model, rig, cfg["camera"]["supersample"], cache_dir,
                          imaging=profile)
    n = len(commands)
    images, T_cam_rig, pose_err = [], [], []
    if verbose:
        print(f"rendering {n} rig views ({optics.name}) ...", file=sys.stderr)
    for k in range(n):
        qpos = {name: vals[k] for name, vals in run.qpos.items()}
        T_world_rig = scene.T_world_table @ T_table_rig[k]
        img, T_world_cam = scene.render(qpos, T_world_rig, seed=cfg["seed"] * 1000 + seed_offset + k)
        images.append(img)
        T_cam_rig.append(invert(T_world_cam) @ T_world_rig)
        T_model = scene.T_world_table @ run.T_table_mount[k]  # the table model's pose of the camera
        pose_err.append(np.abs(T_model - T_world_cam).max())
        if verbose:
            print(f"\r  {k + 1}/{n}", end="", file=sys.stderr)
    if verbose:
        print(file=sys.stderr)
    scene.close()
    port = optics.port
    mag = 1.0 if port is None else port.n_water / port.n_air
    truth = {
        "units": "SI (m, rad, px)",
        "medium": medium, "optics_preset": optics.name, "housing": cfg["camera"]["housing"],
        "imaging": {"profile": profile.name, "stages": {k: dict(v) for k, v in profile.stages.items()},
                    "target_errors": None if target is None else _plain(target)},
        "camera": {"K": true_lens.K.tolist(), "dist": true_lens.dist.tolist(), "width": true_lens.width,
                   "height": true_lens.height, "pixel_pitch": true_lens.pixel_pitch},
        "port": None if port is None else {"d0": port.d0, "t": port.t, "n_air": port.n_air, "n_glass": port.n_glass,
                                           "n_water": port.n_water, "tilt": port.tilt.tolist(),
                                           "decentre": port.decentre.tolist()},
        "focal_effective_px": [mag * true_lens.fx, mag * true_lens.fy],
        "nominal_camera": optics.nominal_camera,
        "rig_corners": rig.features["corners"].tolist(),
        "views": {f"rig{k + 1:02d}": {"T_cam_rig": T_cam_rig[k].tolist(), "table_true": run.true[k].tolist(),
                                      "rig_height_m": float(rig_params[k, 0]), "rig_yaw_rad": float(rig_params[k, 1])}
                  for k in range(n)},
    }
    checks = {"sim_table_pose_err_m": float(max(pose_err)), "views_rendered": float(len(scene.render_s))}
    if scene.render_s:
        checks["render_s"] = float(np.median(scene.render_s))
    checks["plan_render_s"] = time.perf_counter() - t0
    with DatasetWriter(out_dataset, kind="camera_calibration", name=f"{cfg['name']}_{medium}", overwrite=True,
                       command="sim render", identity=cfg["name"],
                       created_by=f"bench sim render {Path(cfg['_file']).name} (seed {cfg['seed']}, {medium})",
                       notes=f"rig photographed by the camera on the x-y table, {optics.name}") as w:
        for k in range(n):
            w.add_view(f"rig{k + 1:02d}", images[k], table=run.read[k], role="rig")
        w.write_text("camera.yaml", camera_yaml_text(nominal))
        w.write_text("target.yaml", rig_target_yaml(profile))  # the rig's stated print tolerances, as in the lab
        w.write_text("truth/truth.yaml", yaml.safe_dump(truth, sort_keys=False))
        w.write_text("truth/sim_checks.json", json.dumps(checks, indent=2) + "\n")
    if verbose:
        print(f"wrote {out_dataset} ({n} views, {optics.name})", file=sys.stderr)
    return checks


def _plain(obj):
    """Numpy arrays and scalars in nested dicts/tuples as plain lists and floats (for YAML)."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return float(obj) if isinstance(obj, (np.floating, float)) else obj


def render(cfg, out_dataset, verbose=True, cache_dir=None) -> dict:
    """Simulate the rig campaign(s) and write the dataset(s) with ``truth/``; returns the simulator's checks.

    One medium: ``out_dataset`` is the dataset; ``camera.medium: both``: ``out_dataset/in_air`` and
    ``out_dataset/in_water`` (one physical camera: the same true lens).
    """
    rng = np.random.default_rng(cfg["seed"])
    first = _optics(cfg, media(cfg)[0])
    t = cfg["truth"]  # the true camera: the nominal lens perturbed (uniform draws)
    lens = draw_true_lens(load_preset(first.lens_camera), rng, imaging(cfg), t["focal_error_pct"],
                          t["principal_error_px"], t["distortion_error_pct"])
    checks = {}
    for i, (medium, path) in enumerate(dataset_dirs(cfg, out_dataset).items()):
        c = _render_medium(cfg, medium, lens, rng, path, cache_dir, verbose, 100 * i)
        checks.update(c if len(media(cfg)) == 1 else {f"{medium}_{k}": v for k, v in c.items()})
    return checks


# ------------------------------------------------------------------------------------------------ thesis tables


def load_table3(path=TABLE3_CSV) -> dict:
    """The thesis's Table 3 (``scenarios/data/table3_thesis.csv``): ``{column: list}``, pictures 1-7 and "average".

    One-line ConfigError naming the file and the row or column when it is malformed.
    """
    _, rows = read_csv_table(path, TABLE3_COLUMNS)
    out = {c: [] for c in TABLE3_COLUMNS}
    for i, row in enumerate(rows, start=1):
        out["picture"].append(row[0].strip())
        for c, v in zip(TABLE3_COLUMNS[1:], row[1:], strict=True):
            out[c].append(csv_number(path, f"row {i}, {c}", v))
    if out["picture"] != [str(k) for k in range(1, 8)] + ["average"]:
        raise ConfigError(path, "picture", "expected pictures 1..7 then 'average'")
    return out


def heikkila_thesis_units(params) -> dict:
    """Heikkilä parameters (:class:`~bench.camera.heikkila.HeikkilaParameters`, SI) in the units of Tables 9/15."""
    return {name: params.f_px if attr == "f" else getattr(params, attr) * scale for name, attr, scale in HEIKKILA_ROWS}


def _heikkila_std(K, dist, cov, pitch) -> dict:
    """Standard errors of the Heikkilä parameters in the units of Tables 9/15 (first-order propagation)."""
    C = heikkila_covariance(K, dist, cov, pitch)
    s = np.sqrt(np.clip(np.diag(C), 0, None))
    return {name: s[i] / pitch if attr == "f" else s[i] * scale for i, (name, attr, scale) in enumerate(HEIKKILA_ROWS)}


# ------------------------------------------------------------------------------------------------ pipeline + scoring


def _opencv_params(K, dist) -> dict:
    return dict(zip(OPENCV_ROWS, [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *np.asarray(dist)[:4]], strict=True))


def _K_dist(names, values):
    """``K, dist`` of a parameter vector in the order of ``CalibrationResult.parameter_names``."""
    v = dict(zip(names, values, strict=True))
    K = np.array([[v["fx"], v.get("skew", 0.0), v["cx"]], [0.0, v["fy"], v["cy"]], [0.0, 0.0, 1.0]])
    dist = np.array([v.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")])
    return K, dist


def _jackknife(rows, names) -> dict:
    """Jackknife standard error of each named value over leave-one-view-out estimates (list of dicts)."""
    V = len(rows)
    if V < 2:
        return {n: float("nan") for n in names}
    cols = {n: np.array([r[n] for r in rows], float) for n in names}
    return {n: float(np.sqrt((V - 1) / V * np.sum((a - a.mean()) ** 2))) if np.all(np.isfinite(a)) else float("nan")
            for n, a in cols.items()}


def _parameter_table(names, nominal, true, est, std, jk, opencv, oracle, fitted, nominal_key="nominal") -> dict:
    """One row per parameter: nominal (or the thesis's), true, estimated, formal and jackknife standard errors,
    error, z-scores against the truth and against the oracle, OpenCV's estimate, the oracle's."""
    nan = float("nan")
    t = {"parameter": list(names), nominal_key: [nominal[n] for n in names], "true": [true[n] for n in names],
         "estimated": [est[n] for n in names],
         "std_error": [std[n] if n in fitted else nan for n in names],
         "jk_std_error": [jk[n] if n in fitted else nan for n in names],
         "error": [est[n] - true[n] for n in names], "opencv": [opencv[n] for n in names],
         "oracle": [oracle[n] for n in names]}

    def z(num, den):
        return [a / b if np.isfinite(b) and b > 0 else nan for a, b in zip(num, den, strict=True)]

    to_oracle = [est[n] - oracle[n] for n in names]
    t["z"], t["z_jk"] = z(t["error"], t["std_error"]), z(t["error"], t["jk_std_error"])
    t["z_oracle"], t["z_oracle_jk"] = z(to_oracle, t["std_error"]), z(to_oracle, t["jk_std_error"])
    return t


def _match_corners(uv, uv_true):
    """Nearest true corner of each extracted one: ``(index (N,), distance (N,) px)``."""
    d = np.linalg.norm(uv[:, None, :] - uv_true[None, :, :], axis=2)
    idx = np.argmin(d, axis=1)
    return idx, d[np.arange(len(uv)), idx]


def _within(z) -> dict:
    z = np.abs(np.asarray(z, float))
    if not np.all(np.isfinite(z)):
        return {f"within_{k}std": float("nan") for k in (1, 2, 3)} | {"max_abs_z": float("nan")}
    return {**{f"within_{k}std": float(np.sum(z <= k)) for k in (1, 2, 3)}, "max_abs_z": float(z.max())}


def evaluate_medium(cfg, medium, ds_dir, out_dir, verbose=True):
    """Run the pipeline on one medium's dataset and score it against its truth.

    Returns ``(metrics, tables, timings_s, artifacts)`` (artifact paths relative to ``out_dir``).
    """
    t0 = time.perf_counter()
    p = cfg["pipeline"]
    model = p["model"]

    def step(text):
        if verbose:
            print(f"  {medium}: {text} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)

    step(f"corners ({p['extractor']} extractor)")
    det = detect_dataset_corners(ds_dir, p["extractor"])
    Xs = det.object_points
    uvs = [u.astype(np.float32).astype(float) for u in det.image_points]  # OpenCV takes float32: same points for both
    size = det.image_size
    t_detect = time.perf_counter() - t0
    t1 = time.perf_counter()
    cal = calibrate_camera(Xs, uvs, size, model=model)
    if not cal.success:
        raise ConfigError(ds_dir, "calibration", cal.message)
    first_pass = None
    if p["refine_corners"] and p["extractor"] == "thesis" and model != "pinhole":
        # second pass: the lines fitted in the ideal pixels of the first calibration (straight there), recalibrate
        first_pass = (det, uvs)
        step("corners again, lines in ideal pixels")
        det = detect_dataset_corners(ds_dir, "thesis", camera=cal.camera)
        Xs = det.object_points
        uvs = [u.astype(np.float32).astype(float) for u in det.image_points]
        cal = calibrate_camera(Xs, uvs, size, model=model)
        if not cal.success:
            raise ConfigError(ds_dir, "calibration", f"after refining the corners: {cal.message}")
    t_cal = time.perf_counter() - t1
    # the rig's stated tolerances (target.yaml) in the calibration's covariance: a paper rig biases the parameters
    # far beyond the pixel noise's standard errors
    tol_draws = 0
    tolerance = load_target_tolerance(Path(ds_dir) / "target.yaml")
    if p["target_tolerance"] and tolerance is not None and tolerance.any:
        step(f"the rig's stated tolerances ({p['tolerance_draws']} calibrations against drawn rigs)")
        cal, _, tol_draws = calibration_with_tolerance(cal, det.geometry, tolerance, Xs, uvs, p["tolerance_draws"],
                                                       Path(ds_dir) / "target.yaml")
    t1 = time.perf_counter()
    ref = opencv_reference(Xs, uvs, size, model)
    t_cv = time.perf_counter() - t1
    # Table 3 is the thesis's procedure: every view alone, pin-hole, on the corners of the thesis's extractor - as
    # printed, its lines fitted to the binary edge map's pixels (§3.3.5: "allocates the non-zero image pixels to the
    # closest line"), unless pipeline.table3_edges is subpixel (the bench's addition, used everywhere else)
    t3_names, t3_uvs = (first_pass[0].names, first_pass[1]) if first_pass is not None else (det.names, uvs)
    t3_X = first_pass[0].object_points if first_pass is not None else Xs
    per_view, chi_subpixel = [], float("nan")
    if cfg["camera"]["preset"] == "air_webcam":
        per_view = per_view_pinhole(t3_X, t3_uvs)
        if p["extractor"] == "thesis":
            chi_subpixel = float(np.mean([r["chi_px"] for r in per_view]))
            if p["table3_edges"] == "pixel":
                step("corners for Table 3 (edge pixels, as printed)")
                det3 = detect_dataset_corners(ds_dir, "thesis", subpixel=False)
                t3_names, t3_X = det3.names, det3.object_points
                t3_uvs = [u.astype(np.float32).astype(float) for u in det3.image_points]  # Figure 44 draws these
                per_view = per_view_pinhole(t3_X, t3_uvs)
    ds = load_dataset(ds_dir)
    nominal = ds.camera()

    # --- the evaluator's part: the truth --------------------------------------------------------------------------
    truth = yaml.safe_load((Path(ds_dir) / "truth" / "truth.yaml").read_text())
    tc = truth["camera"]
    true_cam = CameraModel(tc["width"], tc["height"], np.array(tc["K"]), np.array(tc["dist"]), name="true",
                           pixel_pitch=tc["pixel_pitch"])
    port = None if truth["port"] is None else FlatPort(**{k: (np.array(v) if isinstance(v, list) else v)
                                                          for k, v in truth["port"].items()})
    corners = np.array(truth["rig_corners"])
    uv_true_all = {name: lens_port_projector(true_cam, port)(transform_points(np.array(v["T_cam_rig"]), corners))
                   for name, v in truth["views"].items()}
    err, uv_oracle, dup = [], [], 0
    for name, uv in zip(det.names, uvs, strict=True):
        idx, d = _match_corners(uv, uv_true_all[name])
        dup += len(idx) - len(set(idx.tolist()))
        err.append(d)
        uv_oracle.append(uv_true_all[name][idx])
    err_all = np.concatenate(err)
    oracle = calibrate_camera(Xs, uv_oracle, size, model=model)
    if first_pass is not None:
        e1 = np.concatenate([_match_corners(u, uv_true_all[n])[1] for n, u in zip(first_pass[0].names, first_pass[1],
                                                                                    strict=True)])
        first_pass_rms = float(np.sqrt(np.mean(e1**2)))

    in_water = medium == "water"
    f_true = np.array(truth["focal_effective_px"])
    fx_err = (cal.K[0, 0] / f_true[0] - 1) * 100
    fy_err = (cal.K[1, 1] / f_true[1] - 1) * 100
    m = {
        "reproj_rms_px": cal.rms_px, "opencv_reproj_rms_px": ref.rms_px,
        "reproj_minus_opencv_px": cal.rms_px - ref.rms_px,
        "focal_err_pct": max(abs(fx_err), abs(fy_err)), "fx_err_pct": fx_err, "fy_err_pct": fy_err,
        "opencv_focal_err_pct": max(abs(ref.K[0, 0] / f_true[0] - 1), abs(ref.K[1, 1] / f_true[1] - 1)) * 100,
        "corner_rms_px": float(np.sqrt(np.mean(err_all**2))), "corner_max_px": float(err_all.max()),
        "corner_duplicate_matches": float(dup),
        "corner_rms_px_first_pass": first_pass_rms if first_pass is not None else float("nan"),
        "model_floor_rms_px": oracle.rms_px,
        "oracle_focal_err_pct": max(abs(oracle.K[0, 0] / f_true[0] - 1), abs(oracle.K[1, 1] / f_true[1] - 1)) * 100,
        "views_used": float(len(det.names)), "views_skipped": float(len(det.skipped)),
        "points": float(sum(len(x) for x in Xs)), "sigma_px": cal.sigma_px,
        "tolerance_draws": float(tol_draws),
    }

    # --- parameters: estimate, truth, formal and jackknife standard errors, OpenCV, oracle --------------------------
    pitch = true_cam.pixel_pitch
    heikkila_form = pitch is not None and cal.parameter_names == list(OPENCV_NAMES)
    t1 = time.perf_counter()
    step("jackknife over views")
    _, jk_rows = jackknife_views(Xs, uvs, size, model, result=cal)
    t_jk = time.perf_counter() - t1
    rows_cv = [_opencv_params(*_K_dist(cal.parameter_names, r)) for r in jk_rows]
    nominal_cv = _opencv_params(nominal.K, nominal.dist)
    true_cv = _opencv_params(true_cam.K, true_cam.dist)
    if in_water:  # no true pin-hole camera: only the paraxial focal lengths are defined
        true_cv = {k: float("nan") for k in OPENCV_ROWS} | {"fx_px": f_true[0], "fy_px": f_true[1]}
    std = {k: float("nan") for k in OPENCV_ROWS} | {_CV_KEY.get(name, name): float(sd)
                                                    for name, sd in zip(cal.parameter_names, cal.std, strict=True)}
    fitted = [k for k in OPENCV_ROWS if np.isfinite(std[k])]  # the parameters the model estimates
    intr = _parameter_table(list(OPENCV_ROWS), nominal_cv, true_cv, _opencv_params(cal.K, cal.dist), std,
                            _jackknife(rows_cv, OPENCV_ROWS), _opencv_params(ref.K, ref.dist),
                            _opencv_params(oracle.K, oracle.dist), fitted)
    tables = {"intrinsics": intr}
    score = intr
    if heikkila_form:
        names = [r[0] for r in HEIKKILA_ROWS]

        def h_of(K, dist):
            return heikkila_thesis_units(opencv_to_heikkila(K, dist, pitch))

        thesis = thesis_blocks(load_preset(truth["nominal_camera"]))["heikkila_eq75"]
        h_true = ({n: float("nan") for n in names} | {"f_px": f_true[1], "s_u": f_true[0] / f_true[1]} if in_water
                  else h_of(true_cam.K, true_cam.dist))
        h_rows = [h_of(*_K_dist(cal.parameter_names, r)) if np.all(np.isfinite(r)) else
                  {n: float("nan") for n in names} for r in jk_rows]
        score = tables["heikkila"] = _parameter_table(
            names, thesis, h_true, h_of(cal.K, cal.dist), _heikkila_std(cal.K, cal.dist, cal.covariance, pitch),
            _jackknife(h_rows, names), h_of(ref.K, ref.dist), h_of(oracle.K, oracle.dist), names,
            nominal_key="thesis")
    m["jackknife_s"] = t_jk
    for t in (intr, score) if score is not intr else (intr,):
        for i, n in enumerate(t["parameter"]):
            m[f"err_{n}"], m[f"std_{n}"], m[f"jk_std_{n}"] = t["error"][i], t["std_error"][i], t["jk_std_error"][i]
    fit = [i for i, n in enumerate(score["parameter"]) if np.isfinite(score["std_error"][i])]
    zs = (("heikkila", "z"), ("heikkila_jk", "z_jk"), ("oracle", "z_oracle"), ("oracle_jk", "z_oracle_jk"))
    for label, key in zs:
        vals = [score[key][i] for i in fit]
        if in_water and not label.startswith("oracle"):
            vals = [float("nan")]  # no true Heikkila camera behind a flat port
        m.update({f"{label}_{k}": v for k, v in _within(vals).items()})
    m["heikkila_n_coeffs"] = float(len(fit))

    # --- Table 3 (the webcam): every view calibrated alone (pin-hole, Eq. 55-66, 196) -------------------------------
    if cfg["camera"]["preset"] == "air_webcam":
        cols = ("theta_deg", "alpha_px", "beta_px", "u0_px", "v0_px", "chi_px")
        pictures = [int(n[3:]) if n[:3] == "rig" and n[3:].isdigit() else 0 for n in t3_names]
        t3 = {"picture": [str(k) for k in pictures] + ["average"]}
        thesis3 = load_table3()
        for c in cols:
            vals = [r[c] for r in per_view]
            t3[c] = vals + [float(np.mean(vals))]
        for c in cols:
            t3[f"thesis_{c}"] = [thesis3[c][k - 1] if 1 <= k <= 7 else float("nan") for k in pictures] + \
                [thesis3[c][7]]
        tables["table3"] = t3
        m["table3_alpha_mean_err_pct"] = (t3["alpha_px"][-1] / f_true[0] - 1) * 100
        m["table3_beta_mean_err_pct"] = (t3["beta_px"][-1] / f_true[1] - 1) * 100
        m["table3_theta_mean_deg"] = t3["theta_deg"][-1]
        m["table3_chi_mean_px"] = t3["chi_px"][-1]
        m["table3_chi_subpixel_mean_px"] = chi_subpixel
        for c in ("alpha", "beta"):  # the spread over the pictures (sample std), Table 3's beside it
            m[f"table3_{c}_std_px"] = float(np.std(t3[f"{c}_px"][:-1], ddof=1)) if len(per_view) > 1 else float("nan")
            m[f"thesis_table3_{c}_std_px"] = float(np.std(thesis3[f"{c}_px"][:7], ddof=1))
    tables["views"] = {"view": list(det.names), "chi_px": [float(v) for v in cal.per_view_rms_px],
                       "opencv_chi_px": [float(v) for v in ref.per_view_rms_px],
                       "corner_rms_px": [float(np.sqrt(np.mean(e**2))) for e in err]}

    # --- the other extractor on the same images (corner accuracy only) -----------------------------------------------
    m[f"corner_rms_px_{p['extractor']}_extractor"] = m["corner_rms_px"]
    if p["compare_extractors"]:
        other = "opencv" if p["extractor"] == "thesis" else "thesis"
        step(f"corners by the {other} extractor (comparison)")
        det2 = detect_dataset_corners(ds_dir, other)
        e2 = np.concatenate([_match_corners(u, uv_true_all[n])[1]
                             for n, u in zip(det2.names, det2.image_points, strict=True)])
        m[f"corner_rms_px_{other}_extractor"] = float(np.sqrt(np.mean(e2**2)))
        m[f"views_found_{other}_extractor"] = float(len(det2.names))

    # --- outputs ----------------------------------------------------------------------------------------------------
    out_dir = Path(out_dir)
    write_camera_yaml(out_dir / "camera.yaml", cal.camera.replace(pixel_pitch=pitch) if pitch else cal.camera)
    for name, t in tables.items():
        write_table_csv(out_dir / f"{name}.csv", t)
    artifacts = {"camera": "camera.yaml", **{name: f"{name}.csv" for name in tables}}
    if cfg["outputs"]["plots"]:
        first = ds.view(det.names[0]).image()
        if cfg["camera"]["preset"] == "air_webcam":
            M = dlt.dlt_projection_matrix(t3_X[0], t3_uvs[0])  # Eq. 55-58
            r44 = t3_uvs[0] - dlt.project(M, t3_X[0])  # p_e - p_p (Eq. 195)
            plot_residual_vectors(out_dir / "figure44_residuals.png", t3_uvs[0], r44,
                                  image=ds.view(t3_names[0]).image()[..., ::-1],
                                  title=f"Fig. 44 - {t3_names[0]}: pin-hole (DLT) residuals x50",
                                  rms_px=per_view[0]["chi_px"])
            artifacts["figure44"] = "figure44_residuals.png"
        plot_residual_vectors(out_dir / "residuals.png", uvs[0], cal.residuals_px[0], image=first[..., ::-1],
                              title=f"{det.names[0]}: {model} model residuals x50 ({medium})",
                              rms_px=float(cal.per_view_rms_px[0]))
        artifacts["residuals"] = "residuals.png"
        if model != "pinhole":
            corrected = to_pixels(cal.camera.undistort_pixels(uvs[0]), cal.K)
            fig = "Fig. 59" if in_water else "Fig. 53"
            plot_residual_vectors(out_dir / "figure53_correction.png", uvs[0], corrected - uvs[0],
                                  image=first[..., ::-1], scale=1.0,
                                  title=f"{fig} - {det.names[0]}: extracted corners -> corrected (x1)")
            artifacts["figure53"] = "figure53_correction.png"
    if cfg["outputs"]["rerun"]:  # residual fields per view (bench.scenario.camera_calibration_recording)
        from bench.scenario.camera_calibration_recording import record_camera_calibration

        record_camera_calibration(out_dir / "recording.rrd", cfg, medium, ds, det.names, Xs, uvs, cal, m)
        artifacts["recording"] = "recording.rrd"
    timings = {"detect_s": t_detect, "calibrate_s": t_cal, "opencv_calibrate_s": t_cv,
               "evaluate_s": time.perf_counter() - t0}
    summary = {"medium": medium, "extractor": p["extractor"], "model": model, "views_used": det.names,
               "views_skipped": det.skipped, "message": cal.message, "K": cal.K.tolist(), "dist": cal.dist.tolist(),
               "opencv_K": ref.K.tolist(), "opencv_dist": ref.dist.tolist()}
    atomic_write_text(out_dir / "calibration.json", json.dumps(summary, indent=2, default=float) + "\n")
    return m, tables, timings, artifacts


# ------------------------------------------------------------------------------------------------ printing


def _fmt(v, width=9, prec=None):
    if v is None or not np.isfinite(v):
        return f"{'-':>{width}}"
    if prec is not None:
        return f"{v:>{width}.{prec}f}"
    return f"{v:>{width}.4g}"


def print_table3(t3):
    """Table 3 in the thesis's layout: ours, then the thesis's printed values."""
    names = t3["picture"]
    rows = (("theta", "theta_deg", 1), ("alpha", "alpha_px", 1), ("beta", "beta_px", 1), ("u_0", "u0_px", 1),
            ("v_0", "v0_px", 1), ("chi", "chi_px", 3))
    head = "".join(f"{n if n != 'average' else 'Average':>9}" for n in names)
    for label, prefix in (("ours (simulated rig views, pin-hole per view)", ""), ("thesis Table 3", "thesis_")):
        if f"{prefix}theta_deg" not in t3:
            continue
        print(f"  Table 3 - {label}")
        print(f"  {'param':<7}{head}")
        for name, key, prec in rows:
            print(f"  {name:<7}" + "".join(_fmt(v, 9, prec) for v in t3[prefix + key]))


def print_parameters(t, title, nominal_key):
    """A parameter table (``tables.heikkila`` or ``tables.intrinsics``) beside the nominal/thesis values."""
    print(f"  {title}")
    print(f"  {'param':<12}{nominal_key:>12}{'true':>12}{'ours':>12}{'std err':>11}{'jackknife':>11}{'z':>7}"
          f"{'z_jk':>7}{'OpenCV':>12}{'oracle':>12}")
    for i, n in enumerate(t["parameter"]):
        print(f"  {n:<12}" + "".join(_fmt(t[c][i], 12) for c in (nominal_key, "true", "estimated"))
              + _fmt(t["std_error"][i], 11) + _fmt(t["jk_std_error"][i], 11) + _fmt(t["z"][i], 7, 2)
              + _fmt(t["z_jk"][i], 7, 2) + _fmt(t["opencv"][i], 12) + _fmt(t["oracle"][i], 12))


def run(cfg, out_dir, verbose=True):
    """Render (cached) the campaign(s), calibrate from the datasets, score against the truth, write result.json."""
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    ds_root = out_dir / "dataset"
    cache = out_dir.parent / ".render_cache" if cfg["outputs"]["cache"] else None
    checks = render(cfg, ds_root, verbose=verbose, cache_dir=cache)
    t_render = time.perf_counter() - t0
    ms = media(cfg)
    metrics, tables, timings, artifacts = dict(checks), {}, {"render_s": t_render}, {"dataset": "dataset"}
    per_medium = {}
    for medium, ds_dir in dataset_dirs(cfg, ds_root).items():
        sub = out_dir if len(ms) == 1 else out_dir / medium
        m, t, tm, art = evaluate_medium(cfg, medium, ds_dir, sub, verbose)
        per_medium[medium] = (m, t)
        pre = "" if len(ms) == 1 else f"{medium}_"
        rel = "" if len(ms) == 1 else f"{medium}/"
        metrics.update({pre + k: v for k, v in m.items()})
        tables.update({pre + k: v for k, v in t.items()})
        timings.update({pre + k: v for k, v in tm.items()})
        artifacts.update({pre + k: rel + v for k, v in art.items()})
    if len(ms) == 2:
        metrics.update(per_medium["water"][0])  # the contract names: the camera as it goes subsea (section 5.5)
        tables.update(per_medium["water"][1])
        fa, fw = per_medium["air"][1]["intrinsics"], per_medium["water"][1]["intrinsics"]
        metrics["focal_ratio_water_air"] = fw["estimated"][1] / fa["estimated"][1]
        metrics["thesis_focal_ratio_water_air"] = 662.6 / 510.06  # Table 15 / Table 9
    timings["total_s"] = time.perf_counter() - t0
    path = write_result(out_dir, cfg["name"], cfg["seed"], metrics, tables, timings, artifacts)
    if verbose:
        _print_summary(cfg, per_medium, metrics)
    return path


def _print_summary(cfg, per_medium, metrics):
    print(f"{cfg['name']} (seed {cfg['seed']}): {cfg['camera']['preset']}, extractor {cfg['pipeline']['extractor']}, "
          f"model {cfg['pipeline']['model']}")
    for medium, (m, t) in per_medium.items():
        print(f"  --- {medium}: {int(m['views_used'])} views, {int(m['points'])} corners")
        if cfg["camera"]["preset"] == "air_webcam":
            print_table3(t["table3"])
        if "heikkila" in t:
            table = "Table 15 (in water)" if medium == "water" else "Table 9 (in air)"
            print_parameters(t["heikkila"], f"Heikkila parameters (Eq. 75-76; k in mm^-n, Heikkila's toolbox): thesis "
                                            f"{table} beside ours", "thesis")
        else:
            print_parameters(t["intrinsics"], "multi-view calibration (OpenCV form): nominal (Table 3 average) beside "
                                              "ours", "nominal")
        for k in ("reproj_rms_px", "opencv_reproj_rms_px", "focal_err_pct", "corner_rms_px",
                  "corner_rms_px_thesis_extractor", "corner_rms_px_opencv_extractor", "model_floor_rms_px",
                  "heikkila_within_1std", "heikkila_within_2std", "heikkila_within_3std",
                  "heikkila_jk_within_1std", "heikkila_jk_within_2std", "heikkila_jk_within_3std",
                  "oracle_within_2std", "oracle_jk_within_2std",
                  "table3_alpha_mean_err_pct", "table3_chi_mean_px"):
            if k in m:
                print(f"  {k:<34} {m[k]:.6g}")
    if "focal_ratio_water_air" in metrics:
        print(f"  focal length water / air: ours {metrics['focal_ratio_water_air']:.4f}, thesis (Table 15 / 9) "
              f"{metrics['thesis_focal_ratio_water_air']:.4f}")
