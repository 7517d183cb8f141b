"""The rerun recording of a ``camera_calibration`` run: the residual field of every view, opened on them.

The viewer opens (application id ``camera_calibration: <scenario>``) on a grid of the calibration's views, each the
rig image with its detected corners and the residual vectors of the calibrated model (detected minus predicted,
``p_e - p_p`` as in Figures 44/53, magnified by a factor stated in every view's name: a 1-2-5 step that makes the
median residual about 15 px long), beside a 3D view in the camera frame (OpenCV axes: the camera at the origin, the
two-plane rig drawn as its boards at each view's estimated pose) and the metrics. The recording's name is
``camera_calibration: <scenario>, <medium>, seed <N>``. Everything is static: the views are entities of their own,
``views/<view>`` (a pinhole with the calibrated ``K`` and the image size) with ``views/<view>/image``,
``.../corners`` and ``.../residuals``; ``world/rig/<part>`` the rig's boards - the simulator's nominal rig
(:func:`bench.sim.scenes.rig.calibration_rig`, its black and white squares, borders and backing read back from the
MuJoCo model by :class:`~bench.scenario.scene_meshes.SceneMeshes`) in the rig frame, stored once and drawn at every
view's estimated ``T_cam_target`` (``InstancePoses3D``, one instance per view in the order of the views);
``world/targets/<view>`` the corners at the estimated pose (m), ``world/labels`` the view names at the rigs' tops;
``summary``.
"""

from __future__ import annotations

import numpy as np

from bench.scenario.recording import GREEN, Recording, nice_factor, run_name

YELLOW = (240, 210, 40)
#: Residual arrows are magnified so that the median one spans about this many pixels.
RESIDUAL_TARGET_PX = 15.0
#: The metrics shown first.
KEY_METRICS = ("reproj_rms_px", "opencv_reproj_rms_px", "focal_err_pct", "corner_rms_px", "model_floor_rms_px",
               "views_used", "points")


def record_camera_calibration(path, cfg, medium: str, ds, names, Xs, uvs, cal, metrics):
    """Write the recording of one medium's calibration (see the module docstring); returns its path.

    Parameters
    ----------
    path : path-like
    cfg : dict
        The scenario.
    medium : str
        ``air`` or ``water``.
    ds : Dataset
        The rig views' dataset (images).
    names : list of str
        The views used, in the calibration's order.
    Xs, uvs : lists of ndarray (N_i, 3) m and (N_i, 2) px
        Object points and detected corners per view.
    cal : CalibrationResult
        The calibration (``K``, ``T_cam_target``, ``residuals_px``, ``per_view_rms_px``).
    metrics : dict
    """
    r_all = np.concatenate([np.linalg.norm(r, axis=1) for r in cal.residuals_px]) if names else np.zeros(0)
    k = nice_factor(float(np.median(r_all)) if len(r_all) else 0.0, RESIDUAL_TARGET_PX)
    size = cal.camera.size
    name = cfg["name"]
    rig = rig_mesh()
    with Recording(path, f"camera_calibration: {name}", f"{name}-{medium}-seed{cfg['seed']}",
                   world="opencv", name=run_name("camera_calibration", cfg, medium)) as rec:
        rec.camera("world/camera", np.eye(4), cal.K, size, static=True, plane_distance=0.1)
        if names:  # the rig's boards, stored once, at every view's estimated pose
            for part in rig:
                rec.mesh(f"world/rig/{part.name}", part)
                rec.instances(f"world/rig/{part.name}", cal.T_cam_target)
            tops = np.array([np.asarray(T, float) @ [0.0, 0.0, 0.24, 1.0] for T in cal.T_cam_target])[:, :3]
            rec.stream.log("world/labels", rec.rr.Points3D(tops, labels=list(names), radii=0.003,
                                                           colors=[(240, 240, 240)], show_labels=True), static=True)
        for i, (v, X, uv, r) in enumerate(zip(names, Xs, uvs, cal.residuals_px, strict=True)):
            # each view a pinhole of its own at the origin: its image, corners and residual field (2D only)
            rec.camera(f"views/{v}", np.eye(4), cal.K, size, ds.view(v).image_path, static=True)
            rec.points2d(f"views/{v}/image/corners", uv, GREEN, 2.0, static=True)
            rec.arrows2d(f"views/{v}/image/residuals", uv, k * np.asarray(r), color=YELLOW, radius=1.0, static=True)
            T = np.asarray(cal.T_cam_target[i], float)
            rec.points(f"world/targets/{v}", np.asarray(X) @ T[:3, :3].T + T[:3, 3], color=(200, 200, 200),
                       radius=0.002, static=True)
        first = [m for m in KEY_METRICS if isinstance(metrics.get(m), float)]
        rows = "\n".join(f"| {m} | {metrics[m]:.6g} |" for m in first + sorted(
            m for m, v in metrics.items() if isinstance(v, float) and m not in first))
        per_view = "\n".join(f"| {v} | {rms:.4g} |" for v, rms in zip(names, cal.per_view_rms_px, strict=True))
        rec.text("summary", f"# {name} ({medium}, seed {cfg['seed']})\n\n{cal.message}\n\n"
                            f"**residuals (detected - predicted) x{k:g}**, model {cfg['pipeline']['model']}\n\n"
                            f"| view | rms (px) |\n|---|---|\n{per_view}\n\n| metric | value |\n|---|---|\n{rows}\n")
        rec.blueprint(blueprint(names, cal.per_view_rms_px, k))
    return path


def rig_mesh() -> list:
    """The simulator's nominal two-plane rig (:func:`bench.sim.scenes.rig.calibration_rig`) as meshes in the rig frame
    (the pipeline's target frame, :func:`bench.camera.corners.two_plane_rig`)."""
    from bench.scenario.scene_meshes import SceneMeshes
    from bench.sim.scenes.rig import calibration_rig

    return SceneMeshes([calibration_rig(name="rig")]).merged()


def blueprint(names, rms_px, k: float):
    """Residual fields per view (a grid) beside the camera frame's 3D view and the metrics."""
    import rerun.blueprint as rrb

    fields = [rrb.Spatial2DView(origin=f"/views/{v}", name=f"{v}: residuals x{k:g} (rms {rms:.3g} px)",
                                contents=["$origin/image/**"]) for v, rms in zip(names, rms_px, strict=True)]
    side = rrb.Vertical(rrb.Spatial3DView(origin="/world", name="camera frame: the rig at each view's estimated pose",
                                          eye_controls=rrb.EyeControls3D(position=(-0.75, -0.5, -0.35),
                                                                         look_target=(0.0, 0.0, 0.75),
                                                                         eye_up=(0.0, -1.0, 0.0))),
                        rrb.TextDocumentView(origin="/summary", name="metrics"), row_shares=[1, 1])
    return rrb.Blueprint(rrb.Horizontal(rrb.Grid(*fields), side, column_shares=[2, 1]),
                         rrb.TimePanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         rrb.BlueprintPanel(state="collapsed"), auto_layout=False, auto_views=False)
