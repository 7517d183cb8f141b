"""bench.scenario.recording: what is logged is what rerun's own reader gives back; failures leave no file."""

import numpy as np
import pytest

from bench.geometry.transforms import homogeneous, random_rotation
from bench.scenario.recording import GREEN, RED, Recording, load_entities


def _rgba(c):
    return (c[0] << 24) | (c[1] << 16) | (c[2] << 8) | 255


def test_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    T = homogeneous(random_rotation(rng), [0.1, -0.2, 0.3])
    K = np.array([[900.0, 0.0, 320.5], [0.0, 880.0, 240.25], [0.0, 0.0, 1.0]])
    with Recording(tmp_path / "r.rrd", "test", "test-1") as rec:
        rec.frame("world/base", T, static=True)
        rec.set_time("view", 3)
        rec.camera("world/cam", T, K, (640, 480), keypoints_uv=[[1.0, 2.0], [3.0, 4.0]])
        rec.points("world/p", rng.normal(size=(4, 3)), inliers=[True, False, True, True])
        for d in (20, 30):
            rec.set_time("d_mm", d)
            rec.scalar("plots/err_x_mm", d / 10)
    assert [p.name for p in tmp_path.iterdir()] == ["r.rrd"]  # no temporary file left
    e = load_entities(tmp_path / "r.rrd")
    R = np.array(e["/world/base"]["Transform3D:mat3x3"][0]).reshape(3, 3).T  # column-major in rerun
    assert np.allclose(R, T[:3, :3], atol=1e-6) and np.allclose(e["/world/base"]["Transform3D:translation"][0],
                                                                 T[:3, 3], atol=1e-7)
    assert np.allclose(np.array(e["/world/cam"]["Pinhole:image_from_camera"][0]).reshape(3, 3).T, K)
    assert e["/world/cam"]["Pinhole:resolution"][0] == [[640.0, 480.0]]
    assert list(np.array(e["/world/p"]["Points3D:colors"][0], np.uint32)) == [_rgba(GREEN), _rgba(RED)] + \
        [_rgba(GREEN)] * 2
    assert [v[0] for v in e["/plots/err_x_mm"]["Scalars:scalars"]] == [2.0, 3.0]
    assert e["/world/cam/image/keypoints"]["Points2D:positions"][0] == [[1.0, 2.0], [3.0, 4.0]]


def test_failed_run_leaves_no_recording(tmp_path):
    with pytest.raises(RuntimeError):
        with Recording(tmp_path / "r.rrd", "test", "test-2") as rec:
            rec.frame("world/base", np.eye(4))
            raise RuntimeError("pipeline crashed")
    assert list(tmp_path.iterdir()) == []


def test_nice_factor_is_the_largest_1_2_5_step_that_fits():
    from bench.scenario.recording import nice_factor

    assert nice_factor(0.43e-3, 0.15) == 200.0  # 0.086 m; 500 would give 0.215 m
    assert nice_factor(4.2e-3, 0.15) == 20.0
    assert nice_factor(0.3, 0.15) == 0.5
    assert nice_factor(0.15, 0.15) == 1.0
    assert nice_factor(0.0, 0.15) == 1.0 and nice_factor(float("nan"), 0.15) == 1.0
    rng = np.random.default_rng(5)
    for size in 10.0 ** rng.uniform(-6, 2, 50):
        k = nice_factor(size, 20.0)
        assert k * size <= 20.0 * (1 + 1e-12) and next_step(k) * size > 20.0


def next_step(k):
    m, e = float(f"{k:e}".split("e")[0]), int(f"{k:e}".split("e")[1])
    return {1.0: 2.0, 2.0: 5.0, 5.0: 10.0}[round(m)] * 10.0**e


def test_ellipsoid_mesh_and_blueprint_round_trip(tmp_path):
    """The covariance ellipsoid's axes are the covariance's principal axes; a mesh keeps its triangles; the blueprint's
    views come back by name with their origins and contents."""
    import rerun.blueprint as rrb

    from bench.geometry.quaternion import quaternion_to_matrix
    from bench.scenario.recording import load_blueprint
    from bench.scenario.scene_meshes import MeshPart

    rng = np.random.default_rng(7)
    R = random_rotation(rng)
    cov = R @ np.diag([4e-6, 1e-6, 0.25e-6]) @ R.T
    v = rng.normal(size=(6, 3)).astype(np.float32)
    part = MeshPart("solid", v, np.tile(np.float32([0, 0, 1]), (6, 1)), np.full((6, 4), 200, np.uint8))
    with Recording(tmp_path / "r.rrd", "test", "test-3") as rec:
        rec.ellipsoid("e", [0.1, 0.2, 0.3], cov, 2.0, static=True)
        rec.mesh("m", part)
        rec.blueprint(rrb.Blueprint(rrb.Horizontal(
            rrb.Spatial3DView(origin="/e", name="zoom x20", contents=["+ /e/**", "- /e/x"]),
            rrb.TextDocumentView(origin="/summary", name="metrics"))))
    e = load_entities(tmp_path / "r.rrd")
    half = np.array(e["/e"]["Ellipsoids3D:half_sizes"][0][0])
    x, y, z, w = e["/e"]["Ellipsoids3D:quaternions"][0][0]
    Q = quaternion_to_matrix(np.array([w, x, y, z]))
    assert np.allclose(Q @ np.diag((half / 2.0) ** 2) @ Q.T, cov, atol=1e-12)
    assert np.allclose(np.array(e["/m"]["Mesh3D:vertex_positions"][0]), v)
    assert np.array(e["/m"]["Mesh3D:triangle_indices"][0]).tolist() == [[0, 1, 2], [3, 4, 5]]
    bp = load_blueprint(tmp_path / "r.rrd")
    assert bp["zoom x20"] == {"class": "3D", "origin": "/e", "contents": ["+ /e/**", "- /e/x"]}
    assert bp["metrics"]["class"] == "TextDocument" and bp["metrics"]["origin"] == "/summary"


def test_scene_meshes_are_the_simulated_geometry():
    """The arm's meshes posed by MuJoCo's kinematics put frame 6 where the DH model does; the rig's boards cover the
    corners the rig generator reports; a textured face keeps its texture."""
    pytest.importorskip("mujoco")
    from pathlib import Path

    from bench.robot.kinematics import link_frames
    from bench.robot.model import load_robot, random_errors
    from bench.scenario.scene_meshes import SceneMeshes
    from bench.sim.mjcf import dh_static, error_transform, robot_object
    from bench.sim.scenes.base import place
    from bench.sim.scenes.panel import manifold_panel
    from bench.sim.scenes.rig import calibration_rig

    rng = np.random.default_rng(11)
    robot = load_robot(Path(__file__).resolve().parents[2] / "models" / "ta40.yaml")
    eps = random_errors(rng, trans=2e-3, rot=np.deg2rad(1.0))
    arm = SceneMeshes([robot_object(robot, eps)])
    q = robot.random_configurations(rng, 1)[0]
    poses = arm.body_poses({f"joint{k + 1}": v for k, v in enumerate(q)})
    T6 = poses["link6"] @ dh_static(robot, 6) @ error_transform(eps.reshape(7, 6)[6])
    assert np.allclose(T6, link_frames(robot, q, eps)[-1], atol=1e-9)
    assert sum(p.n_triangles for p in arm.parts["link2"]) > 100

    T_w = homogeneous(random_rotation(rng), [1.0, 2.0, 0.5])
    rig_obj = calibration_rig(name="rig")
    rig = SceneMeshes([place(rig_obj, T_w, "rig_lab")])
    corners = (T_w[:3, :3] @ rig_obj.features["corners"].T).T + T_w[:3, 3]
    verts = np.concatenate([(T[:3, :3] @ p.vertices.T).T + T[:3, 3] for b, T in rig.body_poses().items()
                            for p in rig.parts[b]])
    assert np.all(np.min(np.linalg.norm(verts[None] - corners[:, None], axis=2), axis=1) < 0.03)
    panel = SceneMeshes([manifold_panel(np.random.default_rng(1), 1.2, 0.8, name="panel")], max_texture_px=256)
    back = [p for p in panel.parts["panel"] if p.name == "panel_backplate"][0]
    assert back.texture.shape[2] == 3 and max(back.texture.shape[:2]) == 256
    assert back.texcoords.min() >= 0 and back.texcoords.max() <= 1


def test_recording_name_and_instances_round_trip(tmp_path):
    """The readable recording name (kind, scenario, extra, seed) and a mesh's instance poses come back as logged."""
    from bench.scenario.recording import recording_name, run_name
    from bench.scenario.scene_meshes import MeshPart

    rng = np.random.default_rng(13)
    name = run_name("camera_calibration", {"name": "webcam", "seed": 4}, "water")
    assert name == "camera_calibration: webcam, water, seed 4"
    Ts = np.stack([homogeneous(random_rotation(rng), rng.normal(size=3)) for _ in range(3)])
    part = MeshPart("solid", rng.normal(size=(3, 3)).astype(np.float32), np.tile(np.float32([0, 0, 1]), (3, 1)),
                    np.full((3, 4), 90, np.uint8))
    with Recording(tmp_path / "r.rrd", "test", "test-4", name=name) as rec:
        rec.mesh("rig/solid", part)
        rec.instances("rig/solid", Ts)
    assert recording_name(tmp_path / "r.rrd") == name
    e = load_entities(tmp_path / "r.rrd")["/rig/solid"]
    assert np.allclose(e["InstancePoses3D:translations"][0], Ts[:, :3, 3], atol=1e-6)
    R = np.array(e["InstancePoses3D:mat3x3"][0]).reshape(-1, 3, 3).transpose(0, 2, 1)  # column-major
    assert np.allclose(R, Ts[:, :3, :3], atol=1e-6)
    with Recording(tmp_path / "s.rrd", "test", "test-5") as rec:  # no name: the recording id
        rec.frame("a", np.eye(4), static=True)
    assert recording_name(tmp_path / "s.rrd") == "test-5"


def test_merged_rig_is_the_posed_boards():
    """SceneMeshes.merged: the rig's boards in the rig frame, one coloured mesh, every triangle of every body posed;
    its printed faces hold the rig's corners and its black squares are black."""
    pytest.importorskip("mujoco")
    from bench.scenario.camera_calibration_recording import rig_mesh
    from bench.sim.scenes.rig import calibration_rig

    parts = rig_mesh()
    assert [p.name for p in parts] == ["solid"] and parts[0].texture is None
    v, c = parts[0].vertices, parts[0].colors
    assert len(v) == len(c) and len(v) % 3 == 0 and parts[0].n_triangles > 1000
    corners = calibration_rig(name="rig").features["corners"]
    d = np.min(np.linalg.norm(v[None, ::7] - corners[:, None], axis=2), axis=1)
    assert np.all(d < 0.02)  # a vertex (a square's corner) near every printed corner, in the rig frame
    dark = (c[:, :3] < 20).all(axis=1)
    assert 0.2 < dark.mean() < 0.6  # about half the faces' tiles are black


@pytest.mark.parametrize("xs, timeline", [([20, 50, 100], "d_mm"), ([0.5, 1.5], "d_mm (grid index)")])
def test_sweep_recording_blueprint(tmp_path, xs, timeline):
    """sweep.rrd opens on one plot per metric against the swept key, the bound in its error's plot, timings apart;
    application id and recording name name the scenario; the timeline is the swept key (or its grid index)."""
    from bench.scenario.recording import load_blueprint, recording_name
    from bench.scenario.sweep import summarise

    rng = np.random.default_rng(17)
    rows = [{"params": {"d_mm": d}, "metrics": {"pos_err_mm": float(rng.uniform(1, 3)), "pos_bound_mm": 1.0,
                                                "focal_err_pct": float(rng.uniform()), "run_s": 2.0}}
            for d in xs for _ in range(3)]
    res = summarise(rows, ["d_mm"], tmp_path, "my_scenario")
    bp = load_blueprint(res["recording"])
    plots = {n: v for n, v in bp.items() if v["class"] == "TimeSeries"}
    assert plots["pos_err_mm and pos_bound_mm vs d_mm"]["contents"] == ["+ /metrics/pos_err_mm/**",
                                                                      "+ /metrics/pos_bound_mm/**"]
    assert "focal_err_pct vs d_mm" in plots and "run_s vs d_mm" in plots
    assert not any(n.startswith("pos_bound_mm") for n in plots)  # the bound is drawn with its error only
    assert recording_name(res["recording"]) == "sweep: my_scenario over d_mm"
    e = load_entities(res["recording"])
    assert [v[0] for v in e["/metrics/pos_err_mm"]["Scalars:scalars"]] == pytest.approx(
        res["table"]["pos_err_mm_median"])
    from rerun.chunk import RrdReader

    timelines = {t for c in RrdReader(str(res["recording"])).stream().to_chunks()
                 for t in c.to_record_batch().schema.names if ":" not in t and not t.startswith("rerun")}
    assert timeline in timelines
