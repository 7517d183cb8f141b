"""Scenes: panel, calibration rig, x-y table - compile, render headless, ground truth vs rendered images."""

import os
from dataclasses import replace

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from bench.errors import ConfigError  # noqa: E402
from bench.geometry.transforms import homogeneous, rot_x, rot_z  # noqa: E402
from bench.sim.scenes import textures as tx  # noqa: E402
from bench.sim.scenes.base import (  # noqa: E402
    SceneObject,
    add_geom,
    add_look_at_camera,
    add_texture_material,
    box_mesh,
    compose,
    place,
    save_scene,
    scene_key,
)
from bench.sim.scenes.desk_robot import FACES as DESK_FACES  # noqa: E402
from bench.sim.scenes.desk_robot import desk_robot  # noqa: E402
from bench.sim.scenes.panel import manifold_panel  # noqa: E402
from bench.sim.scenes.rig import SQUARE_M, calibration_rig, planar_board  # noqa: E402
from bench.sim.scenes.xy_table import (  # noqa: E402
    NO_ERRORS,
    TABLE4_CSV,
    TABLE10_CSV,
    UNDERWATER_CAMERA_OFFSET_M,
    TableErrors,
    TableModel,
    lab_table_model,
    load_pose_table,
    random_table_errors,
    table4_commands,
    table10_commands,
    table_commands_from_camera_poses,
    underwater_table_model,
    xy_table,
)

W, H = 640, 480
SIFT_ARGS = dict(contrastThreshold=0.03, edgeThreshold=10)


def _model(objects, extra=None):
    m = compose(objects, extra).compile()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return m, d


def _look(name, eye, target, fovy=45.0, up=(0.0, 0.0, 1.0)):
    """``compose``'s ``extra``: a look-at camera in the world."""
    return lambda spec: add_look_at_camera(spec.worldbody, name, eye, target, fovy, up)


def _key(obj) -> str:
    """The exact fingerprint of an object: its compiled standalone scene (MJB)."""
    return scene_key(compose([obj]).compile()).hexdigest()


#: a camera in the x-y table's mount looking along the mount's z with image y down (the OpenCV optical frame)
def _table_cam(body):
    add_look_at_camera(body, "cam", [0, 0, 0], [0, 0, 1], 27.6, up=(0, -1, 0))


def _render(m, d, camera, depth=False):
    with mujoco.Renderer(m, H, W) as r:
        if depth:
            r.enable_depth_rendering()
        r.update_scene(d, camera=camera)
        return r.render().copy()


def _pinhole(m, d, camera):
    """OpenCV-convention K and T_world_cam of a MuJoCo camera (-z forward, y up -> z forward, y down)."""
    cid = m.camera(camera).id
    f = (H / 2) / np.tan(np.deg2rad(m.cam_fovy[cid]) / 2)
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1.0]])
    R = d.cam_xmat[cid].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
    return K, homogeneous(R, d.cam_xpos[cid])


def _project(K, T_world_cam, p_world):
    p_cam = (np.asarray(p_world) - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
    uv = p_cam[:, :2] / p_cam[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
    return uv, p_cam[:, 2]


def _to_world(T, p):
    return np.asarray(p) @ T[:3, :3].T + T[:3, 3]


# ------------------------------------------------------------------------------------------------------ textures
def test_textures_seeded():
    a = tx.painted_metal(np.random.default_rng(5), (120, 200))
    b = tx.painted_metal(np.random.default_rng(5), (120, 200))
    c = tx.painted_metal(np.random.default_rng(6), (120, 200))
    assert a.shape == (120, 200, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert tx.encode_png(a) == tx.encode_png(b)
    d1 = tx.dial_face(np.random.default_rng(1), 128)
    assert np.array_equal(d1, tx.dial_face(np.random.default_rng(1), 128))
    assert not np.array_equal(d1, tx.dial_face(np.random.default_rng(2), 128))
    with pytest.raises(ValueError, match="texture shape"):
        tx.fractal_noise(np.random.default_rng(0), (4, 100))


def test_box_mesh_uv_orientation():
    """The image's top-left lands on the face's (-x, +y) corner (the convention of box_mesh)."""
    img = np.zeros((64, 64, 3), np.uint8)
    img[:32, :32] = (0, 0, 255)  # top-left red (BGR)
    img[32:, 32:] = (255, 0, 0)  # bottom-right blue
    def build(spec, parent):
        spec.add_mesh(**box_mesh("q", (0.1, 0.1, 0.001)))
        add_texture_material(spec, "q", "q.png", specular=0.0, shininess=0.5)
        add_geom(parent, "q", "mesh", "q", meshname="q")

    obj = SceneObject("q", build, {"q.png": tx.encode_png(img)})
    m, d = _model([obj], _look("c", [0, 0, 0.5], [0, 0, 0], up=(0, 1, 0)))
    px = _render(m, d, "c").astype(int)
    K, T = _pinhole(m, d, "c")
    (u_tl, v_tl), (u_br, v_br) = _project(K, T, [[-0.05, 0.05, 0.001], [0.05, -0.05, 0.001]])[0].round().astype(int)
    assert px[v_tl, u_tl, 0] > 150 and px[v_tl, u_tl, 2] < 60  # red (RGB render)
    assert px[v_br, u_br, 2] > 150 and px[v_br, u_br, 0] < 60  # blue


def test_bad_scene_input_is_refused_in_one_line(tmp_path):
    def sphere(spec, parent):
        add_geom(parent, "g", "sphere", "", [0.1])

    cases = [(ValueError, "lid: box half sizes must be positive", lambda: box_mesh("lid", (0.1, 0.0, 0.1))),
             (ValueError, "scene object names must be unique", lambda: compose([SceneObject("a", sphere)] * 2)),
             (ValueError, "repeated name 'g' in geom",  # MuJoCo's API refuses a name used twice
              lambda: compose([SceneObject("a", sphere), SceneObject("b", sphere)])),
             (ConfigError, "a: x.png: asset file not found",
              lambda: compose([SceneObject("a", sphere, {"x.png": tmp_path / "x.png"})]))]
    for exc, message, call in cases:
        with pytest.raises(exc, match=message) as info:
            call()
        assert "\n" not in str(info.value)


# --------------------------------------------------------------------------------------------------------- panel
@pytest.fixture(scope="module")
def panel():
    return manifold_panel(np.random.default_rng(11))


@pytest.fixture(scope="module")
def panel_view(panel):
    """The panel upright in the world (face normal -> world -y), a camera 1 m in front; colour and depth."""
    T_world_panel = homogeneous(rot_x(np.pi / 2), [0.0, 0.0, 0.6])
    cam = _look("view", [0.03, -1.0, 0.62], [0.0, 0.0, 0.6])
    m, d = _model([place(panel, T_world_panel)], cam)
    return m, d, T_world_panel, _render(m, d, "view"), _render(m, d, "view", depth=True)


def test_panel_seeded(panel):
    again = manifold_panel(np.random.default_rng(11))
    other = manifold_panel(np.random.default_rng(12))
    assert _key(again) == _key(panel) and again.files == panel.files
    assert other.files["panel_backplate.png"] != panel.files["panel_backplate.png"]
    assert _key(replace(other, files=panel.files)) != _key(panel)  # the layout differs, not only the textures


def test_panel_features(panel):
    f = panel.features
    assert len(f["valves"]) == 6 and len(f["receptacles"]) == 2 and len(f["gauges"]) == 3
    assert {v["type"] for v in f["valves"].values()} == {"t_bar", "wheel", "paddle"}
    for v in f["valves"].values():
        assert abs(np.linalg.norm(v["axis"]) - 1) < 1e-12 and abs(v["axis"] @ v["handle_dir"]) < 1e-12
        assert v["axis"][2] >= np.cos(np.deg2rad(30)) - 1e-12  # protrudes from the face, at most 30 deg tilt
        assert np.all(np.abs(v["centre"][:2]) < [0.6, 0.4]) and v["centre"][2] > 0.1
    assert np.allclose(f["corners"], [[-0.6, 0.4, 0], [0.6, 0.4, 0], [0.6, -0.4, 0], [-0.6, -0.4, 0]])
    tilted = [v for v in f["valves"].values() if v["axis"][2] < 0.999]
    assert tilted, "several orientations: at least one tilted stem"


def test_panel_renders_with_keypoints(panel_view):
    m, d, _, img, _ = panel_view
    assert img.shape == (H, W, 3) and img.std() > 20
    sift = cv2.SIFT_create(**SIFT_ARGS)
    n_clear = len(sift.detect(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), None))
    degraded = cv2.GaussianBlur(img.astype(np.float32) * np.array([0.35, 0.75, 0.65], np.float32), (0, 0), 1.5)
    n_water = len(sift.detect(cv2.cvtColor(np.clip(degraded, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY), None))
    print(f"panel SIFT keypoints: clear {n_clear}, attenuated+blurred {n_water}")
    assert n_clear >= 300
    assert n_water >= 150


def test_panel_features_match_rendered_geometry(panel, panel_view):
    """Feature points project onto rendered surfaces at the right depth (truth agrees with the geometry)."""
    m, d, T_wp, _, depth = panel_view
    K, T_wc = _pinhole(m, d, "view")
    f = panel.features
    # gauge dial centres and receptacle fronts are on flat front faces: rendered depth = feature depth (<= 3 mm)
    for group, tol in (("gauges", 0.002), ("receptacles", 0.003), ("docking_buckets", 0.003)):
        pts = np.array([v["centre"] for v in f[group].values()])
        uv, z = _project(K, T_wc, _to_world(T_wp, pts))
        u, v = uv.round().astype(int).T
        assert np.all(np.abs(depth[v, u] - z) < tol), (group, depth[v, u] - z)
    # valve handle centres sit inside the handle hub/bar: the visible surface is a little in front of them
    pts = np.array([v["centre"] for v in f["valves"].values()])
    uv, z = _project(K, T_wc, _to_world(T_wp, pts))
    inside = (uv[:, 0] > 0) & (uv[:, 0] < W - 1) & (uv[:, 1] > 0) & (uv[:, 1] < H - 1)
    u, v = uv[inside].round().astype(int).T
    gap = z[inside] - depth[v, u]
    assert inside.sum() >= 4 and np.all((gap > 0.0) & (gap < 0.03)), gap


def test_panel_texture_override(tmp_path):
    img = np.zeros((50, 80, 3), np.uint8)
    img[:, :40] = 255
    path = tmp_path / "plate.jpg"
    cv2.imwrite(str(path), img)
    p = manifold_panel(np.random.default_rng(3), 0.6, 0.4, texture_overrides={"backplate": path})
    got = cv2.imdecode(np.frombuffer(p.files["panel_backplate.png"], np.uint8), cv2.IMREAD_COLOR)
    assert got.shape[:2] == (680, 1020) and got[:, :500].mean() > 240 and got[:, 520:].mean() < 15
    base = manifold_panel(np.random.default_rng(3), 0.6, 0.4)  # other faces untouched by the override
    assert all(base.files[k] == v for k, v in p.files.items() if k != "panel_backplate.png")
    with pytest.raises(ConfigError, match="missing.png: texture_overrides.gauge_1: texture file not found"):
        manifold_panel(np.random.default_rng(3), 0.6, 0.4, texture_overrides={"gauge_1": tmp_path / "missing.png"})
    with pytest.raises(ConfigError, match="texture_overrides: no_such_face: unknown face"):
        manifold_panel(np.random.default_rng(3), 0.6, 0.4, texture_overrides={"no_such_face": path})
    with pytest.raises(ValueError, match="panel size"):
        manifold_panel(np.random.default_rng(3), 0.1, 0.4)


def test_save_scene_loads_from_path(tmp_path, panel):
    path = save_scene(compose([panel]), tmp_path / "scene")
    m = mujoco.MjModel.from_xml_path(str(path))
    assert m.ntex == len(panel.files)


# ----------------------------------------------------------------------------------------------------------- rig
def _detect_board(gray, uv_expected, pattern=(6, 6)):
    """findChessboardCornersSB on the image masked to one board's region; -> (N, 2) or None."""
    hull = cv2.convexHull(uv_expected.astype(np.float32)).astype(np.int32)
    mask = np.zeros_like(gray)
    cv2.fillConvexPoly(mask, hull, 255)
    mask = cv2.dilate(mask, np.ones((41, 41), np.uint8))
    ok, corners = cv2.findChessboardCornersSB(np.where(mask > 0, gray, 255).astype(np.uint8), pattern,
                                              flags=cv2.CALIB_CB_ACCURACY)
    return corners.reshape(-1, 2) if ok else None


def _max_match_px(detected, expected):
    dist = np.linalg.norm(detected[:, None] - expected[None], axis=2)
    assert len(set(dist.argmin(1))) == len(expected)  # one-to-one
    return dist.min(1).max()


def test_rig_geometry():
    rig = calibration_rig()
    f = rig.features
    assert f["corners"].shape == (72, 3) and abs(SQUARE_M - 0.197 / 7) < 1e-15
    assert np.allclose(f["corners_board_a"][:, 1], 0) and np.allclose(f["corners_board_b"][:, 0], 0)
    # row-major, neighbours one square apart, rows going down
    ca = f["corners_board_a"].reshape(6, 6, 3)
    assert np.allclose(np.linalg.norm(np.diff(ca, axis=1), axis=2), SQUARE_M)
    assert np.allclose(np.diff(ca[:, 0, 2]), -SQUARE_M)
    for T in (f["T_rig_board_a"], f["T_rig_board_b"]):
        assert abs(np.linalg.det(T[:3, :3]) - 1) < 1e-12
    b = planar_board(5, 8, 0.03)
    assert b.features["corners"].shape == (28, 3) and b.features["pattern_size"] == (7, 4)
    assert np.allclose(b.features["corners"][:3], [[0.03, 0.03, 0], [0.06, 0.03, 0], [0.09, 0.03, 0]])
    with pytest.raises(ValueError, match="rows and cols"):
        planar_board(2, 7, 0.03)


def test_rig_corners_project_onto_detections():
    rig = calibration_rig()
    T_wr = homogeneous(rot_z(np.deg2rad(-135.0)), [0.0, 0.0, 0.3])  # concave side towards world -y
    centre = _to_world(T_wr, [0.1, 0.1, 0.12])
    m, d = _model([place(rig, T_wr)], _look("view", centre + [0.06, -0.55, 0.1], centre))
    gray = cv2.cvtColor(_render(m, d, "view"), cv2.COLOR_RGB2GRAY)
    K, T_wc = _pinhole(m, d, "view")
    uv, _ = _project(K, T_wc, _to_world(T_wr, rig.features["corners"]))
    errs = []
    for k in range(2):
        found = _detect_board(gray, uv[36 * k:36 * (k + 1)])
        assert found is not None, f"board {'ab'[k]} not detected"
        errs.append(_max_match_px(found, uv[36 * k:36 * (k + 1)]))
    print(f"rig corner projection vs detection, max px per board: {errs}")
    assert max(errs) <= 0.5


def test_planar_board_oblique_view():
    board = planar_board(7, 9, 0.025, name="pb")
    T_wb = homogeneous(rot_x(-np.pi / 2) @ rot_z(0.2), [0.0, 0.0, 0.4])  # board z (into board) -> world +y
    centre = _to_world(T_wb, [0.1125, 0.0875, 0.0])
    m, d = _model([place(board, T_wb)], _look("view", centre + [0.25, -0.45, 0.12], centre))
    gray = cv2.cvtColor(_render(m, d, "view"), cv2.COLOR_RGB2GRAY)
    K, T_wc = _pinhole(m, d, "view")
    uv, _ = _project(K, T_wc, _to_world(T_wb, board.features["corners"]))
    found = _detect_board(gray, uv, board.features["pattern_size"])
    assert found is not None
    assert _max_match_px(found, uv) <= 0.5


# ------------------------------------------------------------------------------------------------------ x-y table
def test_pose_tables_transcribed():
    t4, t10 = load_pose_table(TABLE4_CSV), load_pose_table(TABLE10_CSV)
    assert len(t4["position"]) == 21 and len(t10["position"]) == 17  # thesis: 21 images (5.2.2), 17 rows (Table 10)
    assert np.array_equal(t4["position"], np.arange(1, 22)) and np.array_equal(t10["position"], np.arange(1, 18))
    assert np.array_equal(t4["dx_mm"], np.arange(-100, 101, 10))
    assert list(t4["theta_y_deg"]) == [6, 5, 4, 4, 3, 3, 2, 1, 1, 0, 0, -1, -2, -2, -3, -4, -5, -5, -6, -7, -8]
    assert list(t10["theta_y_deg"]) == [6, 5, 4, 3, 2, 2, 1, 0, 0, 0, -2, -3, -4, -6, -8, -10, -12]
    assert list(t10["dx_mm"][[0, 4, 10, 16]]) == [-79.5, -40.0, 20.1, 82.2]
    assert list(t10["dz_mm"][[0, 5, 13, 16]]) == [10.4, 3.5, -10.4, -20.8]
    for t in (t4, t10):
        assert not np.any(t["theta_x_deg"]) and not np.any(t["theta_z_deg"]) and not np.any(t["dy_mm"])


def test_table10_is_off_axis_camera_geometry():
    """Table 10's displacements = x commands on a 10 mm grid, z = 0, plus the 100 mm lever arm (to print rounding)."""
    c = table10_commands()
    assert np.all(np.abs(c[:, 0] * 1e3 - np.arange(-80, 81, 10)) < 0.07)
    assert np.all(np.abs(c[:, 1] * 1e3) < 0.06)
    c4 = table4_commands()
    assert np.allclose(c4[:, 0], np.arange(-0.1, 0.1001, 0.01)) and not np.any(c4[:, 1])


def test_table_model_without_errors_is_quantised_commands():
    tm = TableModel(NO_ERRORS)
    cmd = np.array([[0.01234, -0.05678, np.deg2rad(3.04)], [-0.1, 0.1, np.deg2rad(-7.96)]])
    run = tm.run(cmd)
    assert np.allclose(run.read * [1e4, 1e4, 1800 / np.pi], np.round(run.read * [1e4, 1e4, 1800 / np.pi]), atol=1e-9)
    assert np.allclose(run.read, [[0.0123, -0.0568, np.deg2rad(3.0)], [-0.1, 0.1, np.deg2rad(-8.0)]], atol=1e-12)
    assert np.array_equal(run.true, run.read)
    assert np.allclose(run.T_table_mount, run.T_table_mount_nominal, atol=1e-15)
    # camera on the axis: the mount's origin is the carriage position
    assert np.allclose(run.T_table_mount[:, :3, 3], np.c_[run.read[:, 0], np.zeros(2), run.read[:, 1]], atol=1e-15)


def test_table_model_errors_behave_as_specified():
    e = TableErrors(scale_x=3e-4, scale_z=-2e-4, scale_rot=2e-4, backlash_x_m=2e-5, backlash_z_m=3e-5,
                    backlash_rot_rad=np.deg2rad(0.02), orthogonality_rad=1e-4, wobble_rad=5e-5, wobble_phase_rad=0.3)
    tm = TableModel(e, camera_offset_m=UNDERWATER_CAMERA_OFFSET_M)
    cmd = np.array([[0.05, 0.0, 0.0], [0.08, 0.02, 0.1], [0.03, 0.02, 0.05], [0.03, -0.01, 0.05]])
    run = tm.run(cmd)
    s = np.array([e.scale_x, e.scale_z, e.scale_rot])
    b = np.array([e.backlash_x_m, e.backlash_z_m, e.backlash_rot_rad])
    reversed_ = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 1], [1, 1, 1]])  # x reverses at 3, rot at 3, z at 4
    assert np.allclose(run.true, run.read * (1 + s) + reversed_ * b, atol=1e-15)
    assert np.allclose(np.hypot(*run.wobble.T), e.wobble_rad, atol=1e-15)
    assert np.allclose(np.arctan2(run.wobble[:, 1], run.wobble[:, 0]), run.true[:, 2] + e.wobble_phase_rad)
    # orthogonality: a pure z move shifts the carriage along x by z sin(g)
    g_only = TableModel(TableErrors(*[0.0] * 6, orthogonality_rad=1e-3, wobble_rad=0.0)).run([[0.0, 0.1, 0.0]])
    assert np.allclose(g_only.T_table_mount[0, :3, 3], [0.1 * np.sin(1e-3), 0, 0.1 * np.cos(1e-3)], atol=1e-16)
    # true vs nominal mount within the error budget (um-level), never identical
    dp = np.linalg.norm(run.T_table_mount[:, :3, 3] - run.T_table_mount_nominal[:, :3, 3], axis=1)
    assert np.all(dp > 1e-7) and np.all(dp < 1e-4)


def test_table_out_of_travel_is_one_line_config_error():
    tm = lab_table_model()
    with pytest.raises(ConfigError, match=r"x-y table: pose 2: x = 120.0 mm, z = 0.0 mm outside the travel of \+-100"):
        tm.run([[0.0, 0.0, 0.0], [0.12, 0.0, 0.0]])
    with pytest.raises(ConfigError, match="pose 1: contains NaN"):
        tm.read([[np.nan, 0.0, 0.0]])
    with pytest.raises(ValueError, match="expected shape"):
        tm.read([[0.0, 0.0]])
    t = load_pose_table(TABLE4_CSV)
    t["dy_mm"] = t["dy_mm"].copy()
    t["dy_mm"][4] = 1.0
    with pytest.raises(ConfigError, match="position 5: dy_mm"):
        table_commands_from_camera_poses(t)


def test_random_table_errors_seeded():
    a, b = random_table_errors(np.random.default_rng(4)), random_table_errors(np.random.default_rng(4))
    assert a == b and a != random_table_errors(np.random.default_rng(5))
    assert 1e-5 <= a.backlash_x_m <= 5e-5 and 2e-5 <= a.wobble_rad <= 1e-4


def test_table_mjcf_matches_model_and_sees_the_rig():
    """MuJoCo's mount body = T_world_table T_table_mount (truth) to 1e-9; the mounted camera sees the rig where
    the table's kinematics say (the mount frame is the OpenCV optical frame)."""
    tm = underwater_table_model(random_table_errors(np.random.default_rng(8)))
    fovy = float(np.rad2deg(2 * np.arctan(240 / 510.06)))  # Table 9's f = 510 px at 480 rows
    rig = calibration_rig()
    obj = xy_table(tm, lambda b: add_look_at_camera(b, "cam", [0, 0, 0], [0, 0, 1], fovy, up=(0, -1, 0)),
                   reference=rig)
    m, d = _model([obj])
    run = tm.run(table10_commands())
    T_wt, T_tr = obj.features["T_world_table"], obj.features["T_table_reference"]
    body = m.body("table_camera_mount").id
    worst = 0.0
    for i in range(len(run.read)):
        for name, q in run.qpos.items():
            d.qpos[m.joint(name).qposadr[0]] = q[i]
        mujoco.mj_forward(m, d)
        T = T_wt @ run.T_table_mount[i]
        worst = max(worst, np.abs(d.xpos[body] - T[:3, 3]).max(), np.abs(d.xmat[body].reshape(3, 3) - T[:3, :3]).max())
        if i == 8:  # the reference position (Table 10, image 9)
            gray = cv2.cvtColor(_render(m, d, "cam"), cv2.COLOR_RGB2GRAY)
            K, T_wc = _pinhole(m, d, "cam")
            assert np.allclose(T_wc, T, atol=1e-9)
            uv, z = _project(K, T_wc, _to_world(T_wt @ T_tr, rig.features["corners"]))
            assert np.all(z > 0.35) and np.all(z < 0.55)  # rig ~500 mm ahead
            for k in range(2):
                found = _detect_board(gray, uv[36 * k:36 * (k + 1)])
                assert found is not None
                assert _max_match_px(found, uv[36 * k:36 * (k + 1)]) <= 0.5
    assert worst <= 1e-9


def test_lab_table_with_panel_reference_compiles():
    panel = manifold_panel(np.random.default_rng(2), 0.6, 0.45, name="ref")
    obj = xy_table(lab_table_model(), _table_cam, reference=panel)
    assert np.allclose(obj.features["T_table_reference"][:3, 3], [0, 0, 0.7])
    m, d = _model([obj])
    img = _render(m, d, "cam")
    n = len(cv2.SIFT_create(**SIFT_ARGS).detect(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), None))
    assert n >= 300, n


# --------------------------------------------------------------------------------------------------- desk robot
def test_desk_robot_seeded_with_known_faces():
    a, b = desk_robot(np.random.default_rng(3)), desk_robot(np.random.default_rng(3))
    other = desk_robot(np.random.default_rng(4))
    assert _key(a) == _key(b) and a.files == b.files
    assert _key(replace(other, files=a.files)) != _key(a)  # the posture varies by seed, not only the textures
    assert set(a.features["faces"]) == set(DESK_FACES) and all(f"ref_{f}.png" in a.files for f in DESK_FACES)
    with pytest.raises(ConfigError, match="nosuchface"):
        desk_robot(np.random.default_rng(3), texture_overrides={"nosuchface": "x.png"})


def test_desk_robot_on_the_lab_table_has_relief_keypoints_and_highlights():
    """The x-y table sees the desk robot 0.7 m ahead: many SIFT keypoints, depths from the arm to the wall (relief),
    and the ceiling lamp's specular highlights on the metal (the same scene with a lamp of no specular is darker
    there, and only there: the matte wall does not change)."""
    robot = desk_robot(np.random.default_rng(2))
    m, d = _model([xy_table(lab_table_model(), _table_cam, reference=robot)])
    img, depth = _render(m, d, "cam"), _render(m, d, "cam", depth=True)
    n = len(cv2.SIFT_create(**SIFT_ARGS).detect(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), None))
    assert n >= 300, n
    near, far = np.percentile(depth, [2, 98])
    assert near < 0.75 and far > 1.1, (near, far)  # the arm at 0.7-0.9 m, the wall 1.15 m away
    dull = compose([xy_table(lab_table_model(), _table_cam, reference=robot)])
    assert np.allclose(dull.light("ref_lamp").specular, 0.7)  # the lamp as desk_robot makes it
    dull.light("ref_lamp").specular = [0.0] * 3
    m2 = dull.compile()
    d2 = mujoco.MjData(m2)
    mujoco.mj_forward(m2, d2)
    diff = img.astype(float).sum(-1) - _render(m2, d2, "cam").astype(float).sum(-1)
    assert diff.min() > -1e-9 and np.percentile(diff, 99.5) > 30  # highlights: bright, on a small part of the view
    assert np.mean(diff > 30) < 0.2


def test_planar_board_with_print_errors_matches_the_rig_board():
    """A printed board's errors (line offsets, scale, bow) put its corners where the rig's board A has them."""
    from bench.geometry.transforms import invert, transform_points
    from bench.sim.imaging import imaging_profile, target_geometry

    e = target_geometry(imaging_profile("realistic", ["fold"]), 7, np.random.default_rng(5))
    rig = calibration_rig(errors=e)
    board = planar_board(7, 7, errors={"line_offsets_m": e["line_offsets_m"]["a"], "scale": e["scale"],
                                       "bow_sagitta_m": e["bow_sagitta_m"]["a"], "dz_m": e["dz_m"]["a"]})
    expected = transform_points(invert(rig.features["T_rig_board_a"]), rig.features["corners_board_a"])
    assert np.allclose(board.features["corners"], expected, atol=1e-12)
    assert np.abs(board.features["corners"] - planar_board(7, 7).features["corners"]).max() > 1e-4  # perturbed
    with pytest.raises(ValueError, match="line_offsets_m"):
        planar_board(7, 7, errors={"line_offsets_m": (np.zeros(8), np.zeros(5))})
    with pytest.raises(ValueError, match="dz_m"):
        planar_board(7, 7, errors={"dz_m": np.zeros((7, 7))})


def test_cockled_board_renders_where_its_corners_are():
    """A sheet that is not flat (an exaggerated 1 mm cockle and a 1 mm bow) is drawn through its true corners: the
    detections match the projected true corners (to 0.17 px rms: the detector's own error where the four squares
    meeting at a corner are tilted differently), not those of the flat board (1.9 px off)."""
    from bench.sim.imaging import imaging_profile, target_geometry

    prof = imaging_profile("realistic", overrides={"cockle": {"rms_mm": 1.0}, "flatness": {"bow_sagitta_mm": 1.0}})
    e = target_geometry(prof, 7, np.random.default_rng(2), 0.025)
    board = planar_board(7, 7, 0.025, name="pb", errors={"bow_sagitta_m": e["bow_sagitta_m"]["a"],
                                                          "dz_m": e["dz_m"]["a"]})
    T_wb = homogeneous(rot_x(-np.pi / 2) @ rot_z(0.2), [0.0, 0.0, 0.4])
    centre = _to_world(T_wb, [0.0875, 0.0875, 0.0])
    m, d = _model([place(board, T_wb)], _look("view", centre + [0.25, -0.35, 0.12], centre))
    gray = cv2.cvtColor(_render(m, d, "view"), cv2.COLOR_RGB2GRAY)
    K, T_wc = _pinhole(m, d, "view")
    uv, _ = _project(K, T_wc, _to_world(T_wb, board.features["corners"]))
    uv_flat, _ = _project(K, T_wc, _to_world(T_wb, planar_board(7, 7, 0.025).features["corners"]))
    found = _detect_board(gray, uv, board.features["pattern_size"])
    assert found is not None
    err = np.linalg.norm(found - uv, axis=1)
    print(f"cockled board: detection vs true corners max {err.max():.3f} rms {np.sqrt(np.mean(err ** 2)):.3f} px, "
          f"vs flat {np.linalg.norm(found - uv_flat, axis=1).max():.3f} px")
    assert np.sqrt(np.mean(err ** 2)) <= 0.25 and err.max() <= 0.5
    assert np.linalg.norm(found - uv_flat, axis=1).max() > 1.5
