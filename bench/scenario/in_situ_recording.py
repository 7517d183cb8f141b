"""The rerun recording of an ``in_situ`` run: truth and estimates side by side in the site's world frame.

Entities (world = the simulated site, z up; everything the pipeline estimated in its own site frame - the survey
base frame - is drawn through the *true* survey base pose, so estimate and truth meet at the common reference):

* ``world/panel`` outline, ``world/task/valve`` the taught valve handle (true centre);
* ``world/base/survey_true``, ``world/base/locate_true``, ``world/base/locate_estimated`` (frames with axes);
* per view (timeline ``view``): ``world/views/<name>/true`` - the camera at its true pose, its frustum, the image
  and its SIFT keypoints (on the reference image also ``map_keypoints``, those that made the map);
  ``world/views/<name>/estimated`` - where the pipeline believes the camera was (calibrated
  kinematics and mount; for locate views through the located base); ``world/arm/true`` - the arm's frame origins;
  rig views of the lab under ``world/lab/views/<name>`` (base at the lab's origin);
* ``world/map/p1`` - the survey map ¹p (grey), ``world/map/p1_matched`` and ``world/map/p2`` - the pairs used in the
  alignment, inliers green, outliers red;
* ``world/task/arm_compensated`` / ``arm_uncompensated`` - the true arm where the servos took it (re-targeted
  command / taught readings replayed), ``world/task/arm_planned`` - the pipeline's model of the compensated pose;
* ``summary`` - a markdown table of the run's metrics.
"""

from __future__ import annotations

import numpy as np

from bench.robot.kinematics import link_frames
from bench.robot.orientation import link5_frame
from bench.scenario.recording import GREEN, RED, Recording, arm_strip

BLUE = (60, 120, 230)
ORANGE = (240, 150, 30)


def _T(x):
    return np.array(x, dtype=float)


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
    K_hat = camera.K if camera is not None else lab["camera"].K
    size = (camera.width, camera.height) if camera is not None else (int(2 * K_eff[0, 2] + 1), int(2 * K_eff[1, 2] + 1))
    T_site_b2 = res.T_world_base if res.success else None

    with Recording(path, cfg["name"], f"{cfg['name']}-seed{cfg['seed']}") as rec:
        corners = _T(truth["panel_corners_world"])
        rec.lines("world/panel", [np.vstack([corners, corners[:1]])], color=(200, 200, 200), static=True)
        rec.frame("world/base/survey_true", T_wb1, 0.2, static=True)
        rec.frame("world/base/locate_true", T_wb2, 0.2, static=True)
        if T_site_b2 is not None:
            rec.frame("world/base/locate_estimated", T_wb1 @ T_site_b2, 0.2, static=True)
        task = truth.get("task")
        if task:
            rec.points("world/task/valve", [task["centre_world"]], color=ORANGE, radius=0.012, static=True)

        images = [v for v in ds.views if v.image_path is not None]
        for n, v in enumerate(images):
            rec.set_time("view", n)
            t = truth["views"][v.name]
            T_wb, q_true = _T(t["T_world_base"]), _T(t["q_true"])
            kp = obs[v.name].features.uv if v.name in obs else None
            lab_view = v.role == "rig"
            prefix = "world/lab/views" if lab_view else "world/views"
            T_w_cam = T_wb @ link5_frame(robot, q_true, eps_true) @ mount_true
            rec.camera(f"{prefix}/{v.name}/true", T_w_cam, K_eff, size, v.image_path, kp)
            rec.lines("world/arm/true", [arm_strip(T_wb @ link_frames(robot, q_true, eps_true))], color=BLUE)
            # the pipeline's belief: lab views in the lab base, survey views in the site (= survey base) frame
            T_site_cam = link5_frame(robot, v.q, eps_hat) @ mount_hat
            if v.role == "locate":
                if T_site_b2 is None:
                    continue
                T_site_cam = T_site_b2 @ T_site_cam
            T_anchor = T_wb if lab_view else T_wb1
            rec.camera(f"{prefix}/{v.name}/estimated", T_anchor @ T_site_cam, K_hat, size)

        kmap = details.get("map")
        ref = [v for v in images if v.role == "reference"]
        if kmap is not None and len(kmap) and ref:  # the reference keypoints that made it into the map
            rec.set_time("view", images.index(ref[0]))
            rec.stream.log(f"world/views/{ref[0].name}/true/image/map_keypoints",
                           rec.rr.Points2D(kmap.features.uv, radii=2.5, colors=[ORANGE]))
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
                strip = arm_strip(T_wb2 @ link_frames(robot, reached[key], eps_true))
                rec.lines(f"world/task/arm_{key}", [strip], color=color, static=True)
        t_cmd = report.get("tasks", {}).get(task["view"]) if task else None
        if t_cmd and t_cmd["success"] and T_site_b2 is not None:
            # the pipeline's model of the compensated pose: the command on the calibrated arm at the located base
            planned = T_wb1 @ T_site_b2 @ link_frames(robot, np.deg2rad(t_cmd["q_command_deg"]), eps_hat)
            rec.lines("world/task/arm_planned", [arm_strip(planned)], color=(200, 200, 60), static=True)

        rows = "\n".join(f"| {k} | {v:.6g} |" for k, v in sorted(metrics.items()) if isinstance(v, float))
        rec.text("summary", f"# {cfg['name']} (seed {cfg['seed']})\n\n{res.message}\n\n| metric | value |\n|---|---|\n"
                            f"{rows}\n")
    return path
