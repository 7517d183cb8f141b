"""The rerun recording of an ``xy_table`` run, in the table frame (OpenCV axes: x right, y down, z forward).

Entities: ``world/reference/<body>/<part>`` the reference object as the simulator drew it - the textured manifold
panel, the desk robot in its lab corner or the two-plane rig, its meshes read back from the MuJoCo model
(:class:`~bench.scenario.scene_meshes.SceneMeshes`) at its true pose ``T_table_reference``; the panel's texture is a
seeded draw, redrawn by :func:`bench.scenario.xy_table.replay_reference_object` (checked against the dataset's true
camera matrix; when the replay is out of step, the outline or corners of ``truth.yaml`` are drawn as
``world/reference/outline`` instead); per view (static: each view is its own entity) ``world/views/<view>/true`` (the
camera at its true pose, frustum, image) and ``world/views/<view>/estimated`` (the pose from the readings, the nominal
table and the estimated mount rotation R0); ``world/estimates/<method>`` - the estimated positions of every pair's
camera (anchored at the true reference camera) and ``world/estimates/true`` the true ones;
``plots/err_<axis>_mm/<method>`` - the RMS error over the combinations on the timeline ``d_o_mm``, the intraocular
distance (the sweep axis of Tables 5-8 / 11-14, thesis values beside as ``plots/thesis_err_<axis>_mm/<method>``);
``summary``.

The viewer opens (application id ``xy_table: <scenario>``, recording name ``xy_table: <scenario>, seed <N>``) on the
error against the intraocular distance - one plot per axis, ours and the thesis's per method - beside the camera track
(true and estimated cameras, the estimated positions per method) and the metrics.
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import transform_points
from bench.scenario.recording import GREY, Recording, run_name

COLOURS = {"quaternion": (230, 120, 40), "quaternion_ratio": (240, 190, 40), "lms": (60, 120, 230),
           "lms_ratio": (40, 200, 60), "bundle": (200, 60, 200)}


def _outline(truth):
    T = np.array(truth["T_table_reference"])
    if truth.get("reference_corners") is not None:
        return None, transform_points(T, np.array(truth["reference_corners"]))
    if truth.get("panel_size_m") is None:  # the desk robot: nothing but its meshes outlines it
        return None, None
    w, h = truth["panel_size_m"]
    c = np.array([[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0], [w / 2, h / 2, 0], [-w / 2, h / 2, 0], [-w / 2, -h / 2, 0]])
    return transform_points(T, c), None


def reference_scene(cfg, truth):
    """The reference object's meshes (in its own frame) as the simulator drew it, or None (replay out of step)."""
    from bench.scenario.scene_meshes import SceneMeshes
    from bench.scenario.xy_table import replay_reference_object

    obj = replay_reference_object(cfg, truth)
    return None if obj is None else SceneMeshes([obj])


def record_xy_table(path, cfg, ds, truth, result, camera, summary, metrics):
    """Write the recording of one run (see the module docstring); returns its path."""
    K_true = np.array(truth["camera_K"])
    size = tuple(int(v) for v in truth["camera_size"])
    T_true = {n: np.array(T) for n, T in truth["T_table_cam"].items()}
    scene = reference_scene(cfg, truth)
    with Recording(path, f"xy_table: {cfg['name']}", f"{cfg['name']}-seed{cfg['seed']}", world="opencv",
                   name=run_name("xy_table", cfg)) as rec:
        if scene is not None:
            rec.bodies("world/reference", scene, np.array(truth["T_table_reference"], float), static=True)
        else:
            outline, corners = _outline(truth)
            if outline is not None:
                rec.lines("world/reference/outline", [outline], color=(200, 200, 200), static=True)
            elif corners is not None:
                rec.points("world/reference/outline", corners, radius=0.003, static=True)
        views = [v for v in ds.views if v.name in T_true]
        for v in views:  # static: a view's image is never without its pinhole
            rec.camera(f"world/views/{v.name}/true", T_true[v.name], K_true, size, v.image_path, plane_distance=0.05,
                       static=True)
            if v.name in result.T_table_cam:
                rec.camera(f"world/views/{v.name}/estimated", result.T_table_cam[v.name], camera.K, size,
                           plane_distance=0.05, static=True)
        ref = [v.name for v in views if v.role == "reference"] or [views[0].name]
        c_ref = T_true[ref[0]][:3, 3]
        est = {}
        for c in result.combinations:
            if c.success:
                est.setdefault(c.method, []).append(c_ref + c.p_table)
        for m, pts in est.items():
            rec.points(f"world/estimates/{m}", np.array(pts), color=COLOURS.get(m, GREY), radius=0.002, static=True)
        rec.points("world/estimates/true", np.array([T[:3, 3] for T in T_true.values()]), radius=0.003, static=True)
        rr = rec.rr
        for m in sorted(set(summary["method"])):  # ours as lines, the thesis's as markers, one colour per method
            for ax in "xyz":
                rec.stream.log(f"plots/err_{ax}_mm/{m}", rr.SeriesLines(colors=[COLOURS.get(m, GREY)], widths=[2.0],
                                                                         names=[f"{m} (ours)"]), static=True)
                rec.stream.log(f"plots/thesis_err_{ax}_mm/{m}", rr.SeriesPoints(
                    colors=[COLOURS.get(m, GREY)], markers=["cross"], marker_sizes=[4.0], names=[f"{m} (thesis)"]),
                    static=True)
        for i, (d, m) in enumerate(zip(summary["d_mm"], summary["method"], strict=True)):
            rec.set_time("d_o_mm", int(round(d)))
            for ax in "xyz":
                rec.scalar(f"plots/err_{ax}_mm/{m}", summary[f"err_{ax}_mm"][i])
                if f"thesis_err_{ax}_mm" in summary and summary[f"thesis_err_{ax}_mm"][i] is not None:
                    rec.scalar(f"plots/thesis_err_{ax}_mm/{m}", summary[f"thesis_err_{ax}_mm"][i])
        rows = "\n".join(f"| {k} | {v:.6g} |" for k, v in sorted(metrics.items()) if isinstance(v, float))
        rec.text("summary", f"# {cfg['name']} (seed {cfg['seed']})\n\n{result.message}\n\n| metric | value |\n"
                            f"|---|---|\n{rows}\n")
        rec.blueprint(blueprint(sorted(est)))
    return path


def blueprint(methods):
    """Error against the intraocular distance (x, y, z; ours and the thesis's) beside the camera track."""
    import rerun.blueprint as rrb

    plots = [rrb.TimeSeriesView(origin="/plots", name=f"{ax} error (mm) vs intraocular distance d_o (mm)",
                                contents=[f"+ /plots/err_{ax}_mm/**", f"+ /plots/thesis_err_{ax}_mm/**"],
                                axis_x=rrb.TimeAxis(link=rrb.components.LinkAxis.LinkToGlobal),
                                plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightTop))
             for ax in "xyz"]
    track = rrb.Spatial3DView(origin="/world", name="camera track: true and estimated cameras, estimated positions "
                                                    f"({', '.join(methods)})")
    return rrb.Blueprint(rrb.Horizontal(rrb.Vertical(*plots), rrb.Vertical(track, rrb.TextDocumentView(
        origin="/summary", name="metrics"), row_shares=[3, 2]), column_shares=[1, 1]),
                         rrb.TimePanel(timeline="d_o_mm", play_state="following"),
                         rrb.SelectionPanel(state="collapsed"), rrb.BlueprintPanel(state="collapsed"),
                         auto_layout=False, auto_views=False)
