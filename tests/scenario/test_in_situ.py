"""Smoke version of the TA-40 in-situ scenario (fewer views, no supersampling) and the truth-separation check."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("mujoco")

from bench.geometry.transforms import transform_points  # noqa: E402
from bench.scenario.in_situ import replay_panel  # noqa: E402
from bench.scenario.metrics import check_metrics  # noqa: E402
from bench.scenario.runner import load_scenario, run_scenario_file  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "ta40_in_situ_manifold.yaml"
# implementation checks on the ideal image chain; the in-situ goals under realistic imaging come from sweeps
# (docs/realistic_imaging.md)
SMOKE = ["camera.supersample=1", "lab.rig_views=7", "lab.tracker_poses=60", "outputs.cache=false",
         "survey.offsets_mm=[[130, 0], [-130, 0], [0, 130], [0, -130]]", "bound.mc_trials=4", "camera.imaging=ideal"]


@pytest.fixture(scope="module", params=["underwater_in_water", "air_webcam"])
def smoke_run(tmp_path_factory, request):
    out = tmp_path_factory.mktemp("insitu") / "run"
    path = run_scenario_file(SCENARIO, out=out, seed=2, overrides=SMOKE + [f"camera.preset={request.param}",
                                                                            "bound.ml_trials=4"],
                             verbose=False, quiet=True)
    return out, json.loads(Path(path).read_text()), request.param


def test_smoke_accuracy(smoke_run):
    _, res, preset = smoke_run
    m = res["metrics"]
    assert check_metrics("in_situ", res["metrics"]) == ([], [])  # (undeclared, missing)
    assert m["sim_vs_fk_max_err_m"] <= 1e-9 and m["sim_vs_pinocchio_max_err_m"] <= 1e-9
    assert m["marker_projection_rms_px"] <= 0.1
    assert m["reproj_rms_px"] < 0.2 and m["focal_err_pct"] < 0.3  # the camera calibrated from the rig views
    assert m["arm_heldout_rms_mm"] < 0.1  # the arm calibrated from the tracker points
    underwater = preset == "underwater_in_water"
    # in water the port's tilt turns the principal ray by ~0.3 deg, shared by the intrinsics and the mount (see
    # in_situ._effective_camera): 0.3-0.5 deg at full size, ~0.8 deg with this smoke-size rig campaign
    assert m["mount_pos_err_mm"] < 5 and m["mount_rot_err_deg"] < (1.0 if underwater else 0.5)
    assert m["map_points"] > 50 and m["inliers"] > 20
    # SIFT's second orientations at one pixel: about a quarter of the map; the bound counts each detection once
    assert 0 < m["keypoint_twin_points"] < 0.5 * m["map_points"]
    # smoke-size campaign: the full-size targets (2 mm, 0.05 deg over 20 seeds) are `make reproduce`'s business
    assert m["base_pos_err_mm"] < 10 and m["base_rot_err_deg"] < 0.3
    assert m["base_pos_err_mm"] < 5 * m["base_pos_std_mm"] + 1.0  # consistent with the reported uncertainty
    # the signed errors (bench budget's paired displacements) are the scored errors' components
    for name, unit in (("base_pos_err", "mm"), ("base_rot_err", "deg"), ("valve_tool_err", "mm")):
        v = [m[f"{name}_{a}_{unit}"] for a in "xyz"]
        assert np.linalg.norm(v) == pytest.approx(m[f"{name}_{unit}"], rel=1e-9)
    # the bound: measured SIFT noise is sub-pixel; the ideal estimator cannot beat the Cramér-Rao bound by much
    assert 0.005 < m["keypoint_sigma_px"] < 1.0 and m["keypoint_sigma_matches"] > 100
    # the locate views' own noise: the survey's times their ratio on the same tracks, on the panel's true surfaces
    assert 0 < m["keypoint_locate_ratio"] < 5 and m["keypoint_locate_points"] > 20
    # each as the Fisher information of the errors' measured density has it (a few per cent from the robust sigma)
    assert 0.7 < m["keypoint_fisher_factor"] < 1.5 and 0.7 < m["keypoint_locate_fisher_factor"] < 1.5
    assert m["keypoint_sigma_bound_px"] == pytest.approx(m["keypoint_sigma_px"] * m["keypoint_fisher_factor"])
    assert m["keypoint_sigma_locate_px"] == pytest.approx(m["keypoint_sigma_px"] * m["keypoint_locate_ratio"]
                                                          * m["keypoint_locate_fisher_factor"])
    # the Cramér-Rao bound against a Monte Carlo of refine 'joints' under the bound's model (4 draws: loose)
    assert 0.4 < m["base_pos_crb_mm"] / m["base_pos_crb_mc_mm"] < 2.5 and 0 < m["base_rot_bound_deg"]
    assert m["base_pos_bound_mm"] == pytest.approx(np.hypot(m["base_pos_crb_mm"], m["base_pos_floor_mm"]))
    assert m["base_pos_efficiency"] == pytest.approx(m["base_pos_bound_mm"] / m["base_pos_err_mm"])
    # the taught valve task: re-targeted from the located base it lands within millimetres; replayed blindly it misses
    assert m["valve_tool_err_mm"] < 3.0 and m["valve_tool_err_uncompensated_mm"] > 10 * m["valve_tool_err_mm"]
    # the tool tip's protection radius: the base covariance at the tip, at least the floor, and holding its error
    assert 0.5 <= m["valve_protection_radius_mm"] and m["valve_tool_err_mm"] < m["valve_protection_radius_mm"]
    # test 7: the simulated INS (vehicle.yaml) agrees with the located tilt of a clean run, unless 1-6 refused it
    assert (0 <= m["integrity_tilt_sq"] < 13.8) if not m["integrity_refused"] else np.isnan(m["integrity_tilt_sq"])
    # fused (the default, unless refused): the bound took the INS too - its rotation CRB below the images' alone (the
    # tilt and heading split of the CRB without it), and the images' own pose scored beside the fused one
    out, _, _ = smoke_run
    fused = json.loads((out / "locate.json").read_text())["ins_tilt"] == "fused"
    assert fused == (not m["integrity_refused"])
    vision_rot = np.hypot(m["base_rot_crb_tilt_deg"], m["base_rot_crb_heading_deg"])
    assert (m["base_rot_crb_deg"] < vision_rot) if fused else m["base_rot_crb_deg"] == pytest.approx(vision_rot)
    assert np.isfinite(m["base_pos_err_vision_mm"]) and np.isfinite(m["base_pos_bound_vision_mm"])
    assert set(res) == {"scenario", "seed", "metrics", "tables", "timings_s", "artifacts"}


def test_replayed_panel_is_the_rendered_one(smoke_run):
    """The evaluator's replay of the site panel from the seed (ray casting onto its true surfaces) is the panel the
    render drew: the same valves and corners where truth.yaml has them."""
    out, res, preset = smoke_run
    cfg = load_scenario(SCENARIO, seed=res["seed"], overrides=SMOKE + [f"camera.preset={preset}"])
    truth = yaml.safe_load((out / "dataset" / "truth" / "truth.yaml").read_text())
    panel = replay_panel(cfg)
    T = np.array(truth["T_world_panel"], float)
    assert np.allclose(transform_points(T, panel.features["corners"]), truth["panel_corners_world"], atol=1e-12)
    for name, valve in panel.features["valves"].items():
        assert np.allclose(transform_points(T, valve["centre"]), truth["valves_world"][name]["centre"], atol=1e-12)


def test_smoke_realistic_imaging_default(tmp_path):
    """The default imaging (realistic: target print/bow/fold errors, webcam distortion, defocus, motion, rolling
    shutter, Bayer, JPEG - bench.sim.imaging) runs the whole in-situ chain; its accuracy is a sweep's business
    (docs/realistic_imaging.md), the smoke run checks that every stage copes and the goals' figures are finite. It
    also runs the lab calibration that estimates the printed rig (pipeline.refine_rig)."""
    cfg = load_scenario(SCENARIO)
    assert cfg["camera"]["imaging"] == "realistic" and cfg["camera"]["imaging_off"] == []
    overrides = [o for o in SMOKE if not o.startswith("camera.imaging")] + ["bound.enabled=false",
                                                                           "outputs.rerun=false",
                                                                           "pipeline.refine_rig=true"]
    path = run_scenario_file(SCENARIO, out=tmp_path / "run", seed=2, overrides=overrides, verbose=False, quiet=True)
    res = json.loads(Path(path).read_text())
    m = res["metrics"]
    truth = yaml.safe_load((tmp_path / "run" / "dataset" / "truth" / "truth.yaml").read_text())
    from bench.camera.presets import load_preset
    from bench.scenario.in_situ import site_optics
    from bench.sim.imaging import WEBCAM_DISTORTION

    lens = load_preset(site_optics(load_scenario(SCENARIO, overrides=overrides)).lens_camera)
    assert np.allclose(np.array(truth["camera_dist"]) - lens.dist, WEBCAM_DISTORTION)  # the realistic true lens
    for k in ("base_pos_err_mm", "base_rot_err_deg", "valve_tool_err_mm", "reproj_rms_px", "mount_pos_err_mm"):
        assert np.isfinite(m[k]), k
    assert m["map_points"] > 50 and m["inliers"] > 20
    # realistic corners are noisier than ideal ones (0.06 px): the rig calibration sees it
    assert 0.1 < m["reproj_rms_px"] < 1.0


def _numbers(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _numbers(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _numbers(v)
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield float(obj)


def test_no_truth_value_outside_truth(smoke_run):
    out, _, _ = smoke_run
    ds = out / "dataset"
    truth = yaml.safe_load((ds / "truth" / "truth.yaml").read_text())
    secret = {round(v, 9) for key in ("errors", "T_link5_cam", "camera_K", "T_world_base_survey",
                                      "T_world_base_locate") for v in _numbers(truth[key])
              if abs(v) > 1e-6 and abs(abs(v) - 1.0) > 1e-9}
    secret |= {round(v, 9) for view in truth["views"].values() for v in view["q_true"] if abs(v) > 1e-6}
    leaks = []
    for path in ds.rglob("*"):
        if "truth" in path.relative_to(ds).parts or path.suffix not in (".csv", ".yaml"):
            continue
        text = path.read_text()
        for token in text.replace(",", " ").replace("[", " ").replace("]", " ").split():
            try:
                v = float(token)
            except ValueError:
                continue
            for scale in (1.0, 1e-3, np.pi / 180):  # SI, or written in mm / deg
                if round(v * scale, 9) in secret:
                    leaks.append(f"{path.name}: {token}")
    assert not leaks, leaks[:5]


def test_unknown_key_is_one_line_error():
    from bench.errors import ConfigError

    with pytest.raises(ConfigError, match=r"survey.offset_mm: unknown key \(did you mean 'survey.offsets_mm'\?\)"):
        load_scenario(SCENARIO, overrides=["survey.offset_mm=[[1, 2]]"])
    with pytest.raises(ConfigError, match="lab.tracker_sigma_mm: implausible"):
        run_scenario_file(SCENARIO, out="/nonexistent/never", overrides=["lab.tracker_sigma_mm=500"], verbose=False)


def test_recording_loads_back_with_the_run_s_values(smoke_run):
    """The run's .rrd, read back with rerun's own reader, holds the world, poses, cameras, images and point sets."""
    from bench.scenario.recording import load_entities

    out, res, _ = smoke_run
    assert res["artifacts"]["recording"] == "recording.rrd"
    e = load_entities(out / "recording.rrd")
    truth = yaml.safe_load((out / "dataset" / "truth" / "truth.yaml").read_text())
    m = res["metrics"]

    def translation(entity):
        return np.array(e[entity]["Transform3D:translation"][-1], dtype=float)

    def rotation(entity):  # rerun stores 3x3 matrices column-major
        return np.array(e[entity]["Transform3D:mat3x3"][-1], dtype=float).reshape(3, 3).T

    T1, T2 = np.array(truth["T_world_base_survey"]), np.array(truth["T_world_base_locate"])
    assert np.allclose(translation("/world/base/survey_true"), T1[:3, 3], atol=1e-6)
    assert np.allclose(rotation("/world/base/locate_true"), T2[:3, :3], atol=1e-6)
    # the estimate is drawn through the true survey base: its offset from the truth is the scored base error
    err_mm = np.linalg.norm(translation("/world/base/locate_estimated") - T2[:3, 3]) * 1e3
    assert err_mm == pytest.approx(m["base_pos_err_mm"], abs=1e-3)
    views = [v for v in truth["views"]]
    cams = [k for k in e if k.endswith("/true") and "/views/" in k]
    assert len(cams) == len(views) and all(f"{k}/image" in e for k in cams)
    ref_img = e["/world/views/ref/true/image"]["EncodedImage:blob"][0][0]  # row 0, blob 0 of the batch
    assert bytes(ref_img) == (out / "dataset" / "images" / "ref.png").read_bytes()
    K = np.array(e["/world/views/ref/true"]["Pinhole:image_from_camera"][0]).reshape(3, 3).T
    assert np.allclose(K, truth["camera_K_effective"], rtol=1e-6)
    assert len(e["/world/map/p1"]["Points3D:positions"][0]) == m["map_points"]
    colors = np.array(e["/world/map/p2"]["Points3D:colors"][0], dtype=np.uint32)
    green = (40 << 24) | (200 << 16) | (60 << 8) | 255
    assert int(np.sum(colors == green)) == m["inliers"]
    assert "/world/task/valve" in e and "/world/task/arm_uncompensated/link6" in e and "/summary" in e
    # the compensated arm exists when the task was re-targeted (not on a refused localisation)
    assert ("/world/task/arm_compensated/link6" in e) == bool(np.isfinite(m["valve_tool_err_mm"]))
    # the arm as meshes: one pose of every link per view, its meshes once
    assert len(e["/world/arm/link6"]["Transform3D:translation"]) == len(views)
    assert len(e["/world/arm/link6/solid"]["Mesh3D:vertex_positions"]) == 1
    # the panel as the simulator built it: its textured backplate, its valves where truth.yaml has them
    assert "Mesh3D:albedo_texture_buffer" in e["/world/site/panel/panel_backplate"]
    for valve, v in truth["valves_world"].items():  # seeded draws: the body's stem axis and the true handle
        body = f"/world/site/panel_{valve}"
        assert np.allclose(rotation(body)[:, 2], v["axis"], atol=1e-6)
        assert np.allclose(np.cross(np.array(v["centre"]) - translation(body), v["axis"]), 0, atol=1e-6)
    assert "/world/lab/rig/rig_board_a/solid" in e
    # the zoomed base view: the arrow is the error exaggerated by the factor the view's name states
    from bench.scenario.recording import load_blueprint

    bp = load_blueprint(out / "recording.rrd")
    zoom = [n for n in bp if n.startswith("base error x")]
    assert len(zoom) == 1 and bp[zoom[0]]["origin"] == "/base_error"
    k = float(zoom[0].split("x")[1].split()[0])
    arrow = np.array(e["/base_error/error"]["Arrows3D:vectors"][0][0])
    assert np.linalg.norm(arrow) / k * 1e3 == pytest.approx(m["base_pos_err_mm"], rel=1e-6)
    # the images' pose before the INS's tilt was fused, and the correction's arrow ending at the fused estimate
    vision = np.array(e["/base_error/ins_correction"]["Arrows3D:origins"][0][0])
    assert np.linalg.norm(vision) / k * 1e3 == pytest.approx(m["base_pos_err_vision_mm"], rel=1e-6)
    corr = np.array(e["/base_error/ins_correction"]["Arrows3D:vectors"][0][0])
    assert np.allclose(vision + corr, arrow, atol=1e-12)
    assert bp["site: arm, panel, cameras, map, base frames"]["origin"] == "/world"
    locate = [n for n in bp if n.startswith("locate")]
    assert len(locate) == 2 and all(f"{bp[n]['origin']}/image/matches" in e for n in locate)
    assert all(f"{bp[n]['origin']}/image/residuals" in e for n in locate)


def test_every_error_source_off_is_exact(tmp_path):
    """The budget's floor: perfect features, optics model, kinematics and encoders leave no error at all where the
    camera is central (in air: the whole chain - survey map, RANSAC, alignment, refinement, task re-targeting - is
    exact on exact data; behind a flat port the best central model leaves the model floor, docs/bounds.md)."""
    perfect = [f"sources.{k}=perfect" for k in ("features", "camera", "kinematics", "encoders")]
    perfect.append("camera.preset=air_webcam")
    path = run_scenario_file(SCENARIO, out=tmp_path / "run", seed=3, verbose=False, quiet=True,
                             overrides=SMOKE + perfect + ["bound.enabled=false", "outputs.rerun=false"])
    m = json.loads(Path(path).read_text())["metrics"]
    assert m["base_pos_err_mm"] < 1e-6 and m["base_rot_err_deg"] < 1e-7 and m["valve_tool_err_mm"] < 1e-6


def test_every_error_source_off_is_exact_behind_a_port_with_the_refractive_model(tmp_path):
    """Behind a flat port the refractive camera model (the true lens and port, pipeline.camera_model=refractive)
    leaves no floor: the whole chain - coordinates at each keypoint's depth, passes until the pose settles - is exact
    on exact data, where the best central camera leaves the model floor (docs/bounds.md)."""
    perfect = [f"sources.{k}=perfect" for k in ("features", "camera", "kinematics", "encoders")]
    path = run_scenario_file(SCENARIO, out=tmp_path / "run", seed=3, verbose=False, quiet=True,
                             overrides=SMOKE + perfect + ["bound.enabled=false", "outputs.rerun=false",
                                                          "camera.preset=underwater_in_water",
                                                          "pipeline.camera_model=refractive", "lab.rig_in_air=true"])
    m = json.loads(Path(path).read_text())["metrics"]
    assert m["base_pos_err_mm"] < 1e-6 and m["base_rot_err_deg"] < 1e-7 and m["valve_tool_err_mm"] < 1e-6
    locate = json.loads((tmp_path / "run" / "locate.json").read_text())
    assert "refractive camera: " in locate["message"]
    # the lab's own refractive calibration ran (from the air views' lens and the water views), and its file holds
    # the lens and the port; the dataset has the air views and the housing's datasheet
    from bench.camera.io import read_camera_yaml, read_housing_yaml
    from bench.camera.refractive import RefractiveCamera
    from bench.dataset import load_dataset

    lab = read_camera_yaml(tmp_path / "run" / "calibrated" / "camera.yaml", allow_refractive=True)
    assert isinstance(lab, RefractiveCamera) and 0.3 < lab.working_range_m < 1.5
    assert m["port_d0_err_mm"] < 5 and m["focal_err_pct"] < 3 and m["reproj_rms_px"] < 0.2
    ds = load_dataset(tmp_path / "run" / "dataset")
    assert sum(v.role == "rig_air" for v in ds.views) >= 3
    port, sigma = read_housing_yaml(ds.root / "housing.yaml")
    assert sigma == pytest.approx(3e-3 / np.sqrt(3)) and abs(port.d0 - 0.02) <= 3e-3 + 1e-4


def test_refractive_model_needs_a_port_and_a_known_value(tmp_path):
    from bench.errors import ConfigError
    from bench.scenario.in_situ import validate

    with pytest.raises(ConfigError, match="pipeline.camera_model: needs a camera behind a port in water"):
        validate(load_scenario(SCENARIO, overrides=["camera.preset=air_webcam", "pipeline.camera_model=refractive"]))
    with pytest.raises(ConfigError, match="pipeline.camera_model: expected central or refractive"):
        validate(load_scenario(SCENARIO, overrides=["pipeline.camera_model=polynomial"]))
    with pytest.raises(ConfigError, match="lab.rig_in_air: needs a camera behind a port in water"):
        validate(load_scenario(SCENARIO, overrides=["camera.preset=air_webcam", "lab.rig_in_air=true"]))
    with pytest.raises(ConfigError, match=r"pipeline.camera_model: must be central .* with pipeline.refine_k3"):
        validate(load_scenario(SCENARIO, overrides=["pipeline.refine_k3=true", "pipeline.camera_model=refractive"]))
    with pytest.raises(ConfigError, match=r"pipeline.refine_distortion: must be true .* with pipeline.refine_k3"):
        validate(load_scenario(SCENARIO, overrides=["pipeline.refine_k3=true", "pipeline.refine_distortion=false"]))
    with pytest.raises(ConfigError, match=r"lab.rig_extra_distances_m: must be in \(0.2, 3\) m, got 5 \(item 2 of "):
        validate(load_scenario(SCENARIO, overrides=["lab.rig_extra_distances_m=[0.6, 5]"]))
    with pytest.raises(ConfigError, match="camera.housing_tolerance_mm: must be > 0"):
        validate(load_scenario(SCENARIO, overrides=["camera.housing_tolerance_mm=0"]))
    # a tolerance as large as the lens-to-glass distance would draw a datasheet with d0 <= 0: refused up front
    with pytest.raises(ConfigError, match=r"camera.housing_tolerance_mm: must be below the port's lens-to-glass "
                                          r"distance \(\d+\.\d mm\), got 500"):
        validate(load_scenario(SCENARIO, overrides=["camera.housing_tolerance_mm=500"]))


def test_bad_value_leaves_no_output_folder(tmp_path, capsys):
    from bench.cli import main

    out = tmp_path / "never"
    assert main(["run", str(SCENARIO), "--out", str(out), "--set", "lab.tracker_sigma_mm=-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lab.tracker_sigma_mm: must be > 0" in err[0]
    assert not out.exists()


def test_budget_variants_are_paired(tmp_path, monkeypatch):
    """Switching one error source off (bench budget) changes only that source's draws: with perfect encoders the
    truth (errors, parking, views, tracker campaign) and the tracker points are those of the real run, only the
    readings differ. (Rendering is replaced by blank images: the pairing is in the planning and the draws.)"""
    import csv

    from bench.scenario import in_situ
    from bench.sim import campaign

    class BlankScene:
        def __init__(self, robot, eps, T_wb, mount, cam, *args, **kwargs):
            self.size, self.render_s = (cam.height, cam.width, 3), []

        def render(self, q, seed=0):
            return np.zeros(self.size, np.uint8)

        def close(self):
            pass

    monkeypatch.setattr(campaign, "ArmScene", BlankScene)

    def dataset(variant):
        cfg = load_scenario(SCENARIO, seed=4, overrides=SMOKE + [f"sources.encoders={variant}"])
        in_situ.render(cfg, tmp_path / variant, verbose=False)
        truth = yaml.safe_load((tmp_path / variant / "truth" / "truth.yaml").read_text())
        with open(tmp_path / variant / "tracker.csv") as f:
            tracker = [r for r in csv.DictReader(f)]
        return truth, tracker

    (t_real, tr_real), (t_perf, tr_perf) = dataset("real"), dataset("perfect")
    assert t_real.pop("encoders") != t_perf.pop("encoders")
    assert t_real == t_perf
    xyz = [k for k in tr_real[0] if k.endswith("_mm")]
    assert [[r[k] for k in xyz] for r in tr_real] == [[r[k] for k in xyz] for r in tr_perf]
    joints = [k for k in tr_real[0] if k.endswith("_deg")]
    assert [[r[k] for k in joints] for r in tr_real] != [[r[k] for k in joints] for r in tr_perf]
