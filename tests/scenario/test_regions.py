"""The in-situ localisation over several regions of the panel (``site.regions_m``, the manifest's ``region``): each
region mapped and located, all solved together by one joint bundle, its integrity per region, and a region whose
views are faulty left out."""

import shutil

import numpy as np
import pytest
import yaml

pytest.importorskip("mujoco")

from bench.dataset import load_dataset  # noqa: E402
from bench.errors import ConfigError  # noqa: E402
from bench.geometry.transforms import rotation_angle  # noqa: E402
from bench.scenario.runner import kind_module, load_scenario  # noqa: E402
from bench.vision.locate_dataset import locate_dataset  # noqa: E402
from tests.scenario.test_integrity import SCENARIO, SMALL, render_with_oracle  # noqa: E402

TWO = [*SMALL, "site.regions_m=[[0, 0], [0.2, 0]]", "bound.enabled=false", "task.teach=false"]


@pytest.fixture(scope="module")
def two_regions(tmp_path_factory):
    """A small two-region dataset and the evaluator's oracle calibration files (true camera, arm errors, mount)."""
    tmp = tmp_path_factory.mktemp("regions")
    camera, robot, truth = render_with_oracle(tmp, TWO)
    T_true = np.linalg.inv(np.array(truth["T_world_base_survey"])) @ np.array(truth["T_world_base_locate"])
    return tmp, camera, robot, T_true


def _only(src, dst, region):
    """A copy of the dataset with the posed views of the other regions removed (as if one region were surveyed)."""
    shutil.copytree(src, dst)
    man = yaml.safe_load((src / "manifest.yaml").read_text())
    drop = {v["name"] for v in man["views"] if v.get("region", "") not in ("", region)}
    man["views"] = [v for v in man["views"] if v["name"] not in drop]
    (dst / "manifest.yaml").write_text(yaml.safe_dump(man, sort_keys=False))
    rows = (src / "joints.csv").read_text().splitlines()
    (dst / "joints.csv").write_text("\n".join(r for r in rows if r.split(",")[0] not in drop) + "\n")
    return dst


def _r1_images_swapped(src, dst):
    """A copy of the dataset with the images of region r1's first locate view and its second survey view swapped."""
    shutil.copytree(src, dst)
    a, b = dst / "images" / "r1_locate0.png", dst / "images" / "r1_survey02.png"
    a_bytes = a.read_bytes()
    a.write_bytes(b.read_bytes())
    b.write_bytes(a_bytes)
    return dst


def _errors(res, T_true):
    T = res.T_world_base
    return (np.linalg.norm(T[:3, 3] - T_true[:3, 3]) * 1e3,
            np.rad2deg(rotation_angle(T[:3, :3].T @ T_true[:3, :3])))


def test_the_views_carry_their_region(two_regions):
    tmp, *_ = two_regions
    ds = load_dataset(tmp / "ds")
    regions = {v.name: v.region for v in ds.views if v.role in ("reference", "surround", "locate")}
    assert set(regions.values()) == {"r0", "r1"}
    assert regions["ref"] == regions["locate0"] == "r0" and regions["r1_ref"] == regions["r1_locate1"] == "r1"
    assert all(v.region == "" for v in ds.views if v.role == "rig")
    truth = yaml.safe_load((tmp / "ds" / "truth" / "truth.yaml").read_text())
    assert set(regions) <= set(truth["views"])
    from bench.scenario.faults import _site_views  # bench faults damages the first region's views only

    assert _site_views(ds) == {"reference": ["ref"], "surround": [f"survey{i:02d}" for i in range(1, 5)],
                               "locate": ["locate0", "locate1"]}


def test_two_regions_are_solved_together_and_tested_each(two_regions, tmp_path):
    tmp, camera, robot, T_true = two_regions
    kw = dict(verbose=False, camera_path=camera, robot_path=robot, refine="joints", seed=3)
    res, rep = locate_dataset(tmp / "ds", None, **kw)
    assert res.success and rep["integrity"] != "refused", rep["integrity_reasons"]
    assert set(rep["regions"]) == {"r0", "r1"} and all(r["solved"] for r in rep["regions"].values())
    assert set(rep["integrity_regions"]) == {"r0", "r1"}
    t = rep["integrity_tests"]
    for name in ("r0", "r1"):  # every test of every region, at the common pose
        for k in ("consensus_locate_a", "relative_pose_mm", "chi2_ratio", "inliers"):
            assert f"{name}/{k}" in t
    assert t["inliers"] == t["r0/inliers"] + t["r1/inliers"] == rep["inliers"]
    assert t["relative_pose_mm"] == pytest.approx(np.hypot(t["r0/relative_pose_mm"], t["r1/relative_pose_mm"])
                                                  / np.sqrt(2), rel=1e-12)
    for k in ("relative_pose_excess_mm", "relative_pose_excess_deg"):  # the part beyond a clean run's, pooled alike
        assert t[k] == pytest.approx(np.hypot(t[f"r0/{k}"], t[f"r1/{k}"]) / np.sqrt(2), rel=1e-12)
        assert 0 <= t[k] <= t[k.replace("excess_", "")]
    n = [t[f"{r}/locate_residuals"] for r in ("r0", "r1")]  # test 3 pooled over the regions
    rms = np.sqrt((n[0] * t["r0/locate_rms_px"] ** 2 + n[1] * t["r1/locate_rms_px"] ** 2) / sum(n))
    assert t["locate_rms_px"] == pytest.approx(rms, rel=1e-12)
    assert t["chi2_ratio"] == pytest.approx(t["locate_rms_px"] / t["survey_rms_px"], rel=1e-12)
    assert t["relative_pose_chi2"] == pytest.approx(t["r0/relative_pose_chi2"] + t["r1/relative_pose_chi2"])
    assert "14 views' joints" in res.message  # 2 x (reference, 4 surrounding, 2 locate)
    err_mm, err_deg = _errors(res, T_true)
    assert err_mm <= rep["protection_radius_mm"] and err_deg <= rep["protection_angle_deg"]
    # more of the panel pins the rotation: the common covariance is no larger than either region's alone (the
    # regions share the camera and the base; each one's own points and joints are added information)
    sd = {}
    for name in ("r0", "r1"):
        r1, rep1 = locate_dataset(_only(tmp / "ds", tmp_path / name, name), None, **kw)
        assert r1.success and "regions" not in rep1
        sd[name] = np.sqrt(np.linalg.eigvalsh(r1.covariance[:3, :3]).max())
    assert np.sqrt(np.linalg.eigvalsh(res.covariance[:3, :3]).max()) < min(sd.values())


def test_a_region_with_swapped_images_adds_nothing(two_regions, tmp_path):
    """An image swapped between two views of region r1: r1's thesis estimator finds no pose (or its tests refuse
    it), and region r0 alone answers, inside its protection radius."""
    tmp, camera, robot, T_true = two_regions
    ds = _r1_images_swapped(tmp / "ds", tmp_path / "ds")
    res, rep = locate_dataset(ds, None, verbose=False, camera_path=camera, robot_path=robot, refine="joints", seed=3)
    assert rep["integrity"] != "refused", rep["integrity_reasons"]
    assert rep["integrity_regions"]["r1"] in ("not localised", "left out"), rep["integrity_regions"]
    assert rep["regions"]["r1"]["solved"] is False and rep["regions"]["r0"]["solved"] is True
    assert "r1/inliers" not in rep["integrity_tests"] and "7 views' joints" in res.message
    err_mm, err_deg = _errors(res, T_true)
    assert err_mm <= rep["protection_radius_mm"] and err_deg <= rep["protection_angle_deg"]


def test_a_region_whose_joint_reading_is_off_is_left_out(two_regions, tmp_path):
    """Joint 1 of a locate view of region r1 read 1 deg off: together the regions are refused; of the two subsets
    without one region only r0 alone holds, so r1 is left out - a warning (a fault was found), inside its protection
    radius."""
    tmp, camera, robot, T_true = two_regions
    ds = tmp_path / "ds"
    shutil.copytree(tmp / "ds", ds)
    rows = (ds / "joints.csv").read_text().splitlines()
    for i, r in enumerate(rows):
        if r.startswith("r1_locate0,"):
            f = r.split(",")
            f[1] = repr(float(f[1]) + 1.0)
            rows[i] = ",".join(f)
    (ds / "joints.csv").write_text("\n".join(rows) + "\n")
    res, rep = locate_dataset(ds, None, verbose=False, camera_path=camera, robot_path=robot, refine="joints", seed=3)
    assert rep["integrity"] == "warning", rep["integrity_reasons"]
    assert rep["integrity_regions"]["r1"] == "left out" and rep["integrity_regions"]["r0"] in ("ok", "warning")
    assert rep["integrity_reasons"][0].startswith("region r1 left out: ")
    assert rep["regions"]["r1"]["solved"] is False and "7 views' joints" in res.message
    err_mm, err_deg = _errors(res, T_true)
    assert err_mm <= rep["protection_radius_mm"] and err_deg <= rep["protection_angle_deg"]


def test_several_regions_need_the_joint_bundle_and_whole_regions(two_regions, tmp_path):
    tmp, camera, robot, _ = two_regions
    with pytest.raises(ConfigError, match=r"2 regions \('r0', 'r1'\) are solved together by refine 'joints'"):
        locate_dataset(tmp / "ds", None, verbose=False, camera_path=camera, robot_path=robot, refine="bundle")
    with pytest.raises(ConfigError, match="PnP"):
        locate_dataset(tmp / "ds", None, verbose=False, camera_path=camera, robot_path=robot, refine="joints",
                       pnp=True)
    ds = tmp_path / "ds"
    shutil.copytree(tmp / "ds", ds)
    man = yaml.safe_load((ds / "manifest.yaml").read_text())
    man["views"] = [v for v in man["views"] if v["name"] != "r1_ref"]
    (ds / "manifest.yaml").write_text(yaml.safe_dump(man, sort_keys=False))
    rows = (ds / "joints.csv").read_text().splitlines()
    (ds / "joints.csv").write_text("\n".join(r for r in rows if not r.startswith("r1_ref,")) + "\n")
    with pytest.raises(ConfigError, match="one view with role 'reference' in region 'r1', found 0"):
        locate_dataset(ds, None, verbose=False, camera_path=camera, robot_path=robot, refine="joints")


@pytest.mark.parametrize("override, key", [
    ("site.regions_m=[[0, 0], [0.7, 0]]", r"site.regions_m\[1\]"),
    ("bound.enabled=true", "bound.enabled"),
    ("pipeline.refine=bundle", "pipeline.refine"),
])
def test_regions_are_checked_before_anything_is_rendered(override, key):
    base = [o for o in TWO if not o.startswith(override.split("=")[0] + "=")]
    with pytest.raises(ConfigError, match=key):  # load_scenario runs the kind's validate
        load_scenario(SCENARIO, seed=3, overrides=[*base, override])


def test_the_covariance_of_several_regions_has_its_own_kappa(two_regions, tmp_path):
    """With the lab priors the joint bundle's covariance is calibrated by its measured optimism: over two regions by
    KAPPA['joints_regions'] (their feature errors do not average out), over one region by KAPPA['joints'] - also
    when the second region of a two-region dataset is left out of the solve."""
    from bench.vision import integrity as I
    from bench.vision.joint_bundle import priors_yaml_text

    tmp, camera, robot, _ = two_regions
    priors = tmp_path / "calibration_priors.yaml"  # loose lab covariances: 10 px, 10 mrad, 10 mm
    priors.write_text(priors_yaml_text(np.eye(4) * 100.0, np.diag([1e-4] * 3 + [1e-4] * 3)))
    kw = dict(verbose=False, camera_path=camera, robot_path=robot, refine="joints", seed=3, priors_path=priors)
    res, rep = locate_dataset(tmp / "ds", None, **kw)
    assert res.success and "14 views' joints" in res.message
    assert rep["covariance_kappa"] == I.KAPPA["joints_regions"]
    _, rep1 = locate_dataset(_only(tmp / "ds", tmp_path / "r0", "r0"), None, **kw)
    assert rep1["covariance_kappa"] == I.KAPPA["joints"]
    ds = _r1_images_swapped(tmp / "ds", tmp_path / "ds")  # r1's estimator finds no pose, r0 is solved alone
    res2, rep2 = locate_dataset(ds, None, **kw)
    assert rep2["regions"]["r1"]["solved"] is False and "7 views' joints" in res2.message
    assert rep2["covariance_kappa"] == I.KAPPA["joints"]


def test_aimed_regions_keep_the_first_regions_eyes_and_turn_to_their_aim_points(tmp_path):
    """``site.region_views: aimed``: region r1's views sit where region r0's do (the same planned eyes; the true arm
    and mount move both alike, to within a few mm) and look at r1's aim point, 0.3 m to the side - where ``shifted``
    would move them 0.3 m."""
    from bench.robot.orientation import link5_frame

    ds_dir = tmp_path / "ds"
    cfg = load_scenario(SCENARIO, seed=3, overrides=[*SMALL, "site.regions_m=[[0, 0], [0.3, 0]]",
                                                     "site.region_views=aimed", "bound.enabled=false",
                                                     "task.teach=false"])
    kind_module("in_situ", SCENARIO).render(cfg, ds_dir, verbose=False)
    truth = yaml.safe_load((ds_dir / "truth" / "truth.yaml").read_text())
    robot, eps = load_dataset(ds_dir).robot(), np.array(truth["errors"])
    T_l5_cam = np.array(truth["T_link5_cam"])

    def camera(name):
        v = truth["views"][name]
        return np.array(v["T_world_base"]) @ link5_frame(robot, np.array(v["q_true"]), eps) @ T_l5_cam

    T_wp = np.array(truth["T_world_panel"])
    aim = T_wp[:3, 3] + T_wp[:3, :3] @ np.array([0.3, 0.0, 0.0])
    def angle(u, v):
        return np.degrees(np.arccos(np.clip(u @ v / np.linalg.norm(u) / np.linalg.norm(v), -1, 1)))

    for name in ("ref", "survey01", "survey03", "locate0", "locate1"):
        T0, T1 = camera(name), camera(f"r1_{name}")
        c0, c1 = T0[:3, 3], T1[:3, 3]
        assert np.linalg.norm(c1 - c0) < 0.01, name  # the same eye (shifted: 0.3 m apart)
        # each looks at its own aim point but for the true arm's and mount's errors (planned on the nominal ones:
        # 3-5 deg here, alike in both), and the two optical axes part by the angle between the aim points
        assert angle(T1[:3, 2], aim - c1) < 6 and angle(T1[:3, 2], T_wp[:3, 3] - c1) > 15, name
        assert abs(angle(T0[:3, 2], T1[:3, 2]) - angle(T_wp[:3, 3] - c0, aim - c1)) < 1.5, name
    with pytest.raises(ConfigError, match="site.region_views"):
        load_scenario(SCENARIO, seed=3, overrides=[*TWO, "site.region_views=tilted"])
