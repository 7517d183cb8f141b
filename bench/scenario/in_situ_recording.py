"""The rerun recording of an ``in_situ`` run: the site as simulated, truth against estimate, opened on the question.

The viewer opens on the blueprint :func:`blueprint` sends (application id ``in_situ: <scenario>``, recording name
``in_situ: <scenario>, seed <N>``, timeline
``view_index`` - the dataset's image views in order, the locate pair last):

* tab **localisation** (active): a large 3D view of the site (``world``: the arm's link meshes at the current view's
  configuration, the textured panel, the cameras with their images, the map, the base frames); beside it
  **base error x k**, the true locate base frame at the origin with the estimate's error exaggerated ``k`` times
  (``k`` a 1-2-5 step chosen so that the error and the 1-sigma ellipsoid fill the view, stated in the view's name and
  in the metrics): the estimated frame, an arrow from the true to the estimated origin and the 1-sigma covariance
  ellipsoid of the estimated position (the localisation's covariance), and the protection radius as a sphere when
  the integrity check gave one; below, the two locate views with the matched keypoints (inliers of the alignment
  green, the rest red) and the reprojection residuals of the inliers (detected keypoint -> the map point projected
  through the located pose and the calibrated camera, magnified by a stated factor); the metrics (markdown);
* tab **survey**: the reference and surrounding views with their keypoints (on the reference, those that made the
  map in orange);
* tab **lab calibration**: the rig views and a 3D view of the lab (rig boards, the arm at the rig views).

Entities (world = the simulated site, z up; what the pipeline estimated in its own site frame - the survey base
frame - is drawn through the *true* survey base pose, so estimate and truth meet at the common reference):

* ``world/site/<body>/<part>`` the panel's meshes (textured), ``world/lab/rig/<body>/<part>`` the rig's boards;
* ``world/arm/<body>`` (``Transform3D`` per view) with its meshes ``world/arm/<body>/<part>``: the true arm;
* ``world/base/survey_true``, ``world/base/locate_true``, ``world/base/locate_estimated`` (frames with axes);
* ``world/views/<name>/true`` (site views) or ``world/lab/views/<name>/true`` (rig views): the camera at its true
  pose, its image and keypoints; ``.../estimated`` where the pipeline believes it was;
* ``world/views/<locate>/true/image/matches`` and ``.../residuals`` (the locate pair);
* ``world/map/p1`` (grey), ``world/map/p1_matched``, ``world/map/p2`` (inliers green, outliers red);
* ``world/task/valve``; ``world/task/arm_compensated/<body>`` and ``world/task/arm_uncompensated/<body>`` the true arm
  where the servos took it (meshes tinted green / red), ``world/task/arm_planned`` the pipeline's model (polyline);
* ``base_error/true``, ``base_error/estimated``, ``base_error/error`` (arrow), ``base_error/covariance``,
  ``base_error/protection``, ``base_error/arm_base`` (the base turret for scale, not exaggerated); with the INS's
  tilt fused, ``base_error/vision`` (the images' own pose, exaggerated alike) and ``base_error/ins_correction`` (the
  arrow from it to the fused estimate);
* ``summary``: the metrics (markdown).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.geometry.quaternion import matrix_to_rotation_vector, rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert
from bench.robot.kinematics import link_frames
from bench.robot.orientation import link5_frame
from bench.scenario.recording import GREEN, GREY, RED, Recording, arm_strip, nice_factor, run_name

ORANGE = (240, 150, 30)
YELLOW = (220, 200, 60)
#: The base-error view shows the error exaggerated so that it (or the 1-sigma ellipsoid) spans about this (m).
ZOOM_TARGET_M = 0.15
#: Reprojection residual arrows are magnified so that the median spans about this many pixels.
RESIDUAL_TARGET_PX = 10.0


#: The metrics shown first in the summary (the question: where is the base, how sure is the pipeline).
KEY_METRICS = ("base_pos_err_mm", "base_rot_err_deg", "base_pos_std_mm", "base_rot_std_deg", "protection_radius_mm",
               "valve_tool_err_mm", "valve_tool_err_uncompensated_mm", "inliers", "map_points")


def _T(x):
    return np.array(x, dtype=float)


def site_scene(cfg, truth):
    """The panel and the rig as the simulator built them, as :class:`~bench.scenario.scene_meshes.SceneMeshes`.

    The panel's layout and textures are seeded draws: they are drawn again exactly as ``in_situ.render`` drew them
    (the truth, then the panel, from ``default_rng(seed)``); a test checks the valves against ``truth.yaml``.
    """
    from bench.robot.model import load_robot
    from bench.scenario.in_situ import _truth
    from bench.scenario.scene_meshes import SceneMeshes
    from bench.sim.scenes.base import place
    from bench.sim.scenes.panel import manifold_panel
    from bench.sim.scenes.rig import calibration_rig

    rng = np.random.default_rng(cfg["seed"])
    _truth(cfg, load_robot(Path(cfg["_file"]).parent / cfg["robot"]), rng)
    site = cfg["site"]
    panel = manifold_panel(rng, site["panel_width_m"], site["panel_height_m"], name="panel")
    return (SceneMeshes([place(panel, _T(truth["T_world_panel"]), "panel_site")]),
            SceneMeshes([place(calibration_rig(name="rig"), _T(truth["T_world_rig"]), "rig_lab")]), panel)


def arm_scene(robot, eps, T_link5_cam, K, size):
    """The arm (true geometry ``eps``) with its camera housing at ``T_link5_cam``, as SceneMeshes."""
    from bench.scenario.scene_meshes import SceneMeshes
    from bench.sim.mjcf import robot_object

    return SceneMeshes([robot_object(robot, eps, None, (np.asarray(K, float), int(size[0]), int(size[1]),
                                                        T_link5_cam))])


def _qpos(q):
    return {f"joint{k + 1}": float(v) for k, v in enumerate(q)}


def locate_residuals(kmap, obs, res, camera, names):
    """Matched keypoints of the locate pair and the reprojection residuals of the alignment's inliers.

    The map <-> a <-> b matches are made again as :func:`bench.vision.insitu.locate` makes them (ratio test and
    orientation filter); a match is an inlier when its map point is one the alignment kept (``res.p1[res.inliers]``).
    The residual of an inlier in view a (b) is the map point projected through the located pose (``res.T_ref_cam``;
    view b through the kinematics' ``T_a_b``) and the calibrated camera, minus the detected keypoint (px). After a
    bundle refinement the map points moved too; the residuals use the survey map's points.

    Returns
    -------
    dict
        Per view name: ``uv (N, 2)`` the matched keypoints, ``inlier (N,)`` bool, ``residual (N, 2)`` (px, NaN for
        outliers).
    """
    from bench.vision.insitu import ViewObservation, reference_matches

    a, b = obs[names[0]], obs[names[1]]
    m_a = reference_matches(ViewObservation("map", kmap.features, kmap.x_ref, np.eye(4)), [a])[0]
    m_ab = reference_matches(a, [b])[0]
    b_of_a = np.full(len(a.features), -1)
    b_of_a[m_ab.i1] = m_ab.i2
    sel = b_of_a[m_a.i2] >= 0
    i_map, i_a = m_a.i1[sel], m_a.i2[sel]
    i_b = b_of_a[i_a]
    kept = {tuple(p) for p in np.asarray(res.p1)[np.asarray(res.inliers, bool)]} \
        if res.p1 is not None and res.inliers is not None else set()
    inlier = np.array([tuple(p) in kept for p in kmap.p_ref[i_map]], dtype=bool)
    if not res.success:
        return {v.name: {"uv": v.features.uv[idx], "inlier": inlier, "residual": np.full((len(idx), 2), np.nan)}
                for v, idx in ((a, i_a), (b, i_b))}
    T_a_ref = invert(res.T_ref_cam)
    T_b_a = invert(invert(a.T_base_cam) @ b.T_base_cam)
    X_a = kmap.p_ref[i_map] @ T_a_ref[:3, :3].T + T_a_ref[:3, 3]
    X_b = X_a @ T_b_a[:3, :3].T + T_b_a[:3, 3]
    out = {}
    for v, idx, X in ((a, i_a, X_a), (b, i_b, X_b)):
        r = camera.project(X) - v.features.uv[idx]
        r[~inlier] = np.nan
        out[v.name] = {"uv": v.features.uv[idx], "inlier": inlier, "residual": r}
    return out


def base_error(T_b1_b2_true, T_b1_b2_hat, cov_site):
    """The estimate's error in the true locate base frame: ``(dt (3,) m, dphi (3,) rad, cov_t (3, 3) m^2)``.

    ``T_err = T_b2_true^-1 T_b2_hat`` (both in the survey base frame, the site frame); the covariance of the
    position (``covariance[3:, 3:]``, site frame) is rotated into the true locate base frame.
    """
    T_err = invert(T_b1_b2_true) @ T_b1_b2_hat
    R = T_b1_b2_true[:3, :3]
    cov_t = R.T @ np.asarray(cov_site, float)[3:, 3:] @ R
    return T_err[:3, 3], matrix_to_rotation_vector(T_err[:3, :3]), cov_t


def record_in_situ(path, cfg, ds, truth, lab, res, report, details, reached, metrics):
    """Write the recording of one run (see the module docstring); returns its path."""
    robot = ds.robot()
    eps_true = _T(truth["errors"])
    mount_true = _T(truth["T_link5_cam"])
    K_eff = _T(truth["camera_K_effective"])
    eps_hat = details.get("eps", lab["eps"])
    mount_hat = details.get("T_link5_cam", lab["mount"].T_mount_cam)
    T_wb1 = _T(truth["T_world_base_survey"])
    T_wb2 = _T(truth["T_world_base_locate"])
    obs = details.get("observations", {})
    camera = details.get("camera")
    if camera is not None and hasattr(camera, "virtual_camera"):  # refractive: its pinhole at the lens, for display
        camera = camera.virtual_camera()
    K_hat = camera.K if camera is not None else lab["camera"].K
    size = (camera.width, camera.height) if camera is not None else tuple(int(v) for v in truth["image_size"])
    T_site_b2 = res.T_world_base if res.success else None
    name = cfg["name"]

    site, rig, _ = site_scene(cfg, truth)
    arm = arm_scene(robot, eps_true, mount_true, K_eff, size)
    with Recording(path, f"in_situ: {name}", f"{name}-seed{cfg['seed']}", name=run_name("in_situ", cfg)) as rec:
        rec.bodies("world/site", site, static=True)
        rec.bodies("world/lab/rig", rig, static=True)
        rec.frame("world/base/survey_true", T_wb1, 0.2, static=True)
        rec.frame("world/base/locate_true", T_wb2, 0.2, static=True)
        if T_site_b2 is not None:
            rec.frame("world/base/locate_estimated", T_wb1 @ T_site_b2, 0.2, static=True)
        task = truth.get("task")
        if task:
            rec.points("world/task/valve", [task["centre_world"]], color=ORANGE, radius=0.012, static=True)

        images = [v for v in ds.views if v.image_path is not None]
        for n, v in enumerate(images):
            rec.set_time("view_index", n)
            t = truth["views"][v.name]
            T_wb, q_true = _T(t["T_world_base"]), _T(t["q_true"])
            kp = obs[v.name].features.uv if v.name in obs else None
            lab_view = v.role in ("rig", "rig_air")
            prefix = "world/lab/views" if lab_view else "world/views"
            T_w_cam = T_wb @ link5_frame(robot, q_true, eps_true) @ mount_true
            # cameras are static (each view is its own entity): their 2D content is never without its pinhole
            rec.camera(f"{prefix}/{v.name}/true", T_w_cam, K_eff, size, v.image_path, kp, static=True)
            rec.bodies("world/arm", arm, T_wb, _qpos(q_true), meshes=n == 0)
            # the pipeline's belief: lab views in the lab base, survey views in the site (= survey base) frame
            T_site_cam = link5_frame(robot, v.q, eps_hat) @ mount_hat
            if v.role == "locate":
                if T_site_b2 is None:
                    continue
                T_site_cam = T_site_b2 @ T_site_cam
            T_anchor = T_wb if lab_view else T_wb1
            rec.camera(f"{prefix}/{v.name}/estimated", T_anchor @ T_site_cam, K_hat, size, static=True)

        kmap = details.get("map")  # with several regions: the map of the region the solve started from
        ref = [v.name for v in images if v.role == "reference"][:1]
        locate_names = [v.name for v in images if v.role == "locate"][:2]
        if details.get("regions_solved"):
            roles = details["regions"][details["regions_solved"][0]][1]
            ref, locate_names = [roles["reference"][0].name], [v.name for v in roles["locate"][:2]]
        if kmap is not None and len(kmap) and ref:  # the reference keypoints that made it into the map
            rec.points2d(f"world/views/{ref[0]}/true/image/map_keypoints", kmap.features.uv, ORANGE, 2.5,
                         static=True)
        res_scale = 1.0
        if kmap is not None and len(kmap) >= 3 and camera is not None and len(locate_names) == 2 and \
                all(n in obs for n in locate_names):
            lr = locate_residuals(kmap, obs, res, camera, locate_names)
            r_all = np.concatenate([np.linalg.norm(d["residual"], axis=1) for d in lr.values()])
            r_all = r_all[np.isfinite(r_all)]
            res_scale = nice_factor(float(np.median(r_all)) if len(r_all) else 0.0, RESIDUAL_TARGET_PX)
            for nm, d in lr.items():
                colors = np.where(d["inlier"][:, None], GREEN, RED).astype(np.uint8)
                rec.points2d(f"world/views/{nm}/true/image/matches", d["uv"], colors, 3.0, static=True)
                ok = np.isfinite(d["residual"][:, 0])
                rec.arrows2d(f"world/views/{nm}/true/image/residuals", d["uv"][ok], res_scale * d["residual"][ok],
                             color=YELLOW, radius=1.0, static=True)
        if kmap is not None and len(kmap):
            T_w_ref = T_wb1 @ kmap.T_world_ref
            rec.points("world/map/p1", (T_w_ref[:3, :3] @ kmap.p_ref.T).T + T_w_ref[:3, 3], static=True)
            if res.p1 is not None and res.inliers is not None and T_site_b2 is not None:
                rec.points("world/map/p1_matched", (T_w_ref[:3, :3] @ res.p1.T).T + T_w_ref[:3, 3],
                           inliers=res.inliers, radius=0.006, static=True)
                T_w_a = T_w_ref @ res.T_ref_cam  # 2p lives in locate camera a's frame
                rec.points("world/map/p2", (T_w_a[:3, :3] @ res.p2.T).T + T_w_a[:3, 3], inliers=res.inliers,
                           radius=0.003, static=True)

        for key, color in (("compensated", GREEN), ("uncompensated", RED)):
            if key in reached:
                rec.bodies(f"world/task/arm_{key}", arm, T_wb2, _qpos(reached[key]), albedo=(*color, 255), static=True)
        t_cmd = report.get("tasks", {}).get(task["view"]) if task else None
        if t_cmd and t_cmd["success"] and T_site_b2 is not None:
            # the pipeline's model of the compensated pose: the command on the calibrated arm at the located base
            planned = T_wb1 @ T_site_b2 @ link_frames(robot, np.deg2rad(t_cmd["q_command_deg"]), eps_hat)
            rec.lines("world/task/arm_planned", [arm_strip(planned)], color=YELLOW, radius=0.004, static=True)

        zoom, centre = _base_error_view(rec, T_wb1, T_wb2, T_site_b2, res, report)
        pr = report.get("protection_radius_mm")
        pr_text = "" if pr is None or not np.isfinite(pr) else (
            f"; protection radius {pr:.3g} mm" + (" (sphere)" if zoom * pr * 1e-3 <= 2 * ZOOM_TARGET_M else
                                                  f" (x{zoom:g} = {zoom * pr * 1e-3:.2g} m: outside the view)"))
        first = [k for k in KEY_METRICS if isinstance(metrics.get(k), float)]
        rows = "\n".join(f"| {k} | {metrics[k]:.6g} |" for k in first + sorted(
            k for k, v in metrics.items() if isinstance(v, float) and k not in first))
        integrity = report.get("integrity")
        integ = "" if integrity is None else (
            f"integrity **{integrity}**" + (f" ({'; '.join(report.get('integrity_reasons') or [])})"
                                            if report.get("integrity_reasons") else "") + "\n\n")
        rec.text("summary", f"# {name} (seed {cfg['seed']})\n\n{res.message}\n\n{integ}"
                            f"**base error view: error x{zoom:g}** (arrow, estimated frame and 1-sigma ellipsoid of "
                            f"the position{pr_text}); **locate residuals x{res_scale:g}**\n\n"
                            f"| metric | value |\n|---|---|\n{rows}\n")
        rec.blueprint(blueprint(images, locate_names, zoom, res_scale, centre, bool(reached)))
    return path


def _base_error_view(rec, T_wb1, T_wb2, T_site_b2, res, report) -> tuple:
    """The zoomed base view (``base_error/...``, the true locate base frame at the origin).

    Returns the factor ``k`` and the exaggerated error ``k dt`` (m; None without an estimate).
    """
    rec.stream.log("base_error", rec.rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.frame("base_error/true", np.eye(4), 0.1, static=True)
    if T_site_b2 is None:
        return 1.0, None
    T_b1_b2 = invert(T_wb1) @ T_wb2
    dt, dphi, cov_t = base_error(T_b1_b2, T_site_b2, res.covariance)
    sigma = float(np.sqrt(max(np.linalg.eigvalsh(cov_t).max(), 0.0))) if np.all(np.isfinite(cov_t)) else 0.0
    k = nice_factor(max(float(np.linalg.norm(dt)), sigma), ZOOM_TARGET_M)
    rec.frame("base_error/estimated", homogeneous(rotation_vector_to_matrix(k * dphi), k * dt), 0.1, static=True)
    rec.arrows("base_error/error", [np.zeros(3)], [k * dt], color=ORANGE, radius=0.0025, static=True)
    if report.get("T_world_base_vision") is not None:  # the images' own pose, before the INS's tilt was fused
        dt_v, dphi_v, _ = base_error(T_b1_b2, np.array(report["T_world_base_vision"], float), res.covariance)
        rec.frame("base_error/vision", homogeneous(rotation_vector_to_matrix(k * dphi_v), k * dt_v), 0.06, static=True)
        rec.arrows("base_error/ins_correction", [k * dt_v], [k * (dt - dt_v)], color=GREY, radius=0.0015,
                   static=True)
    if sigma > 0:
        rec.ellipsoid("base_error/covariance", k * dt, k**2 * cov_t, 1.0, color=(120, 180, 255), static=True)
    pr = report.get("protection_radius_mm")
    if pr is not None and np.isfinite(pr) and k * pr * 1e-3 <= 2 * ZOOM_TARGET_M:  # else it says so in the text
        rec.stream.log("base_error/protection", rec.rr.Ellipsoids3D(
            centers=[k * dt], half_sizes=[[k * pr * 1e-3] * 3], colors=[(230, 80, 200)], line_radii=0.001,
            fill_mode=rec.rr.components.FillMode.MajorWireframe), static=True)
    return k, k * dt


def blueprint(images, locate_names, zoom: float, res_scale: float, centre=None, task: bool = False):
    """The layout the viewer opens on (see the module docstring)."""
    import rerun.blueprint as rrb

    site_views = [v.name for v in images if v.role in ("reference", "surround")]
    rig_views = [v.name for v in images if v.role == "rig"]
    world = rrb.Spatial3DView(
        origin="/world", name="site: arm, panel, cameras, map, base frames",
        contents=["+ /world/**", "- /world/lab/**", "- /world/task/arm_compensated/**",
                  "- /world/task/arm_uncompensated/**", "- /world/task/arm_planned"],
        eye_controls=rrb.EyeControls3D(position=(-0.9, -1.8, 1.8), look_target=(1.0, 0.3, 0.45),
                                       eye_up=(0.0, 0.0, 1.0)))
    c = np.zeros(3) if centre is None else 0.5 * np.asarray(centre, float)
    zoomed = rrb.Spatial3DView(origin="/base_error", name=f"base error x{zoom:g} (true locate base frame)",
                               eye_controls=rrb.EyeControls3D(position=tuple(c + [0.19, -0.28, 0.16]),
                                                              look_target=tuple(c), eye_up=(0.0, 0.0, 1.0)))
    locate = [rrb.Spatial2DView(origin=f"/world/views/{n}/true", name=f"{n}: matches, residuals x{res_scale:g}",
                                contents=["$origin/image/**"]) for n in locate_names]
    metrics = rrb.TextDocumentView(origin="/summary", name="metrics")
    localisation = rrb.Horizontal(
        world,
        rrb.Vertical(rrb.Horizontal(zoomed, metrics, column_shares=[3, 2]), rrb.Horizontal(*locate),
                     row_shares=[1, 1]),
        column_shares=[3, 2], name="localisation")
    tabs = [localisation, rrb.Grid(*[rrb.Spatial2DView(origin=f"/world/views/{n}/true", name=n,
                                                       contents=["$origin/image/**"]) for n in site_views],
                                   name="survey")]
    if task:
        tabs.append(rrb.Spatial3DView(
            origin="/world", name="task: compensated (green), taught readings replayed (red), plan (yellow)",
            contents=["+ /world/site/**", "+ /world/task/**", "+ /world/base/**"],
            eye_controls=rrb.EyeControls3D(position=(-0.6, -1.6, 1.6), look_target=(1.3, 0.4, 0.7),
                                           eye_up=(0.0, 0.0, 1.0))))
    tabs.append(rrb.Horizontal(
        rrb.Spatial3DView(origin="/world", name="lab: rig and arm", contents=["+ /world/lab/**", "+ /world/arm/**"]),
        rrb.Grid(*[rrb.Spatial2DView(origin=f"/world/lab/views/{n}/true", name=n, contents=["$origin/image/**"])
                   for n in rig_views]),
        column_shares=[1, 2], name="lab calibration"))
    return rrb.Blueprint(rrb.Tabs(*tabs, active_tab=0),
                         rrb.TimePanel(timeline="view_index", play_state="following"),
                         rrb.SelectionPanel(state="collapsed"), rrb.BlueprintPanel(state="collapsed"),
                         auto_layout=False, auto_views=False)
