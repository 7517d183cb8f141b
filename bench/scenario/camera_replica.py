"""Scenario kind ``camera_replica``: a real camera's chessboard photos, simulated, and the two calibrations compared.

Does the simulated camera err like a real one (issue 12)? Point this kind at a folder of real photos of a planar
chessboard (``photos.dir``, ``photos.inner_corners``); by default the project's real webcam photos
(``tests/data/real_webcam_chessboard``: 19 views, 640 x 480, 7 x 7 inner corners).

1. **The real photos** are detected (``findChessboardCornersSB`` with ``CALIB_CB_ACCURACY``) and calibrated
   (``photos.model``, Heikkilä by default) by :mod:`bench.camera.photo_stats`.
2. **Their replica**: that calibration is the simulated camera (its K and distortion, the photos' image size) and
   gives each photo's board pose (``T_cam_target``, unit squares scaled to ``photos.square_mm``: a board's square is
   rarely recorded with its photos; it sets the board's absolute size, hence the scale of the print, cockle and
   handling errors). The simulator renders a printed board of ``inner_corners + 1`` squares at those poses through
   the ``air_webcam`` chain under ``camera.imaging`` (lamp, sensor, JPEG...; the realistic target errors drawn from
   the seed: print lines, scale, bow, cockle, and the hand-held board's flexing per photo). The lens is the photos'
   own calibration, so the realistic profile's ``distortion`` stage (the project webcam's lens) is not applied.
3. **The same code** detects and calibrates the renders and summarises both calibrations'
   residuals (:func:`bench.camera.photo_stats.residual_statistics`): RMS, per-view spread, and the correlation of
   residual vectors 1-3 corners apart along a board row and a column; SIFT's localisation noise on the board
   plane (:func:`bench.camera.photo_stats.measure_sift_precision`); and the images themselves - the edge spread,
   the sharpening halo beside an edge, and the noise and level of the black squares
   (:func:`~bench.camera.photo_stats.measure_blur`, :func:`~bench.camera.photo_stats.measure_edge_profile`,
   :func:`~bench.camera.photo_stats.measure_noise`).

Issue 12's acceptance reads the ratio ``rms_ratio`` (simulated / real calibration RMS, target 0.7-1.3) and the
correlations at lag 1. Outputs: ``result.json``, ``per_view.csv``, ``correlation.csv``, ``replica.png`` (per-view
RMS and the correlations, real beside simulated), ``renders/`` (the grey renders, ``outputs.images``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Literal

import cv2
import numpy as np
from pydantic import Field

from bench.camera.photo_stats import (
    calibrate_views,
    detect_board,
    detect_views,
    measure_blur,
    measure_edge_profile,
    measure_noise,
    measure_sift_precision,
    residual_statistics,
)
from bench.config import ImagingParams, PlotOutputs, ScenarioBase, Section, about, at_least, at_most, section
from bench.dataset import photo_files as folder_photos
from bench.errors import BenchError, ConfigError
from bench.fileio import atomic_save_figure, atomic_write_bytes, headless_pyplot
from bench.geometry.transforms import homogeneous
from bench.scenario.results import write_result, write_table_csv
from bench.sim.imaging import profile_from_config

#: the statistics compared, real beside simulated (``residual_statistics``, ``measure_sift_precision``, and the
#: image statistics ``measure_blur``, ``measure_edge_profile``, ``measure_noise``)
STATS = ("rms_px", "per_view_rms_cv", "row_corr_lag1", "row_corr_lag2", "row_corr_lag3", "col_corr_lag1",
         "col_corr_lag2", "col_corr_lag3", "sift_plane_px", "edge_sigma_px", "edge_undershoot_dn", "noise_black_dn",
         "level_black_dn")


class Photos(Section):
    dir: Annotated[str, about("folder of the real photos (.jpg, .jpeg, .png), relative to the scenario file or "
                              "absolute")] = "../tests/data/real_webcam_chessboard"
    inner_corners: Annotated[list[Annotated[int, Field(ge=3, le=40)]], Field(min_length=2, max_length=2), about(
        "the board's inner corners per row, per column (OpenCV's patternSize)")] = [7, 7]
    square_mm: Annotated[float, Field(gt=0), at_least(3, "{v} mm is implausibly small for a printed square"),
                         at_most(300, "{v} mm is implausibly large for a printed square; the unit is mm")] = 25.0
    model: Annotated[Literal["heikkila", "radial", "pinhole"], about(
        "the calibration model, for the photos and their renders alike")] = "heikkila"


class Camera(Section):
    imaging: Annotated[str, about("realistic | ideal (bench.sim.imaging)")] = "realistic"
    imaging_off: Annotated[list[str], about("stages of the profile switched off")] = []
    imaging_params: ImagingParams = {}
    supersample: Annotated[int, Field(ge=1, le=8)] = 3


class Outputs(PlotOutputs):
    images: Annotated[bool, about("write the grey renders to renders/")] = True


class Scenario(ScenarioBase):
    """A ``camera_replica`` scenario file."""

    photos: Photos = section(Photos)
    camera: Camera = section(Camera)
    outputs: Outputs = section(Outputs)


# ------------------------------------------------------------------------------------------------ configuration


def imaging(cfg):
    """The scenario's imaging profile (``camera.imaging``, ``camera.imaging_off``)."""
    return profile_from_config(cfg, "camera")


def photo_files(cfg) -> list:
    """The photos of ``photos.dir`` (sorted); one-line ConfigError when the folder is missing or holds none."""
    given = cfg["photos"]["dir"]  # messages quote it as written (relative to the scenario file's folder, or absolute)
    folder = Path(cfg["_file"]).parent / given
    if not folder.is_dir():
        raise ConfigError(cfg["_file"], "photos.dir", f"{given}: not a folder (relative to the scenario file's)")
    files = folder_photos(folder)
    if len(files) < 3:
        raise ConfigError(cfg["_file"], "photos.dir", f"{given}: {len(files)} photos (.jpg, .jpeg, .png); a "
                                                      "calibration needs at least 3")
    return files


def validate(cfg) -> None:
    """The checks the model cannot make: the imaging profile, and a folder of photos."""
    imaging(cfg)
    photo_files(cfg)


# ------------------------------------------------------------------------------------------------ the real photos


def calibrate_photos(cfg, verbose=False):
    """``(views, calibration)`` of the real photos; one-line errors when too few show the board or their sizes
    differ."""
    files = photo_files(cfg)
    pattern = tuple(cfg["photos"]["inner_corners"])
    views = detect_views(files, pattern)
    odd = next((v for v in views if v.grey.shape != views[0].grey.shape), None)
    if odd is not None:
        (h, w), (h0, w0) = odd.grey.shape, views[0].grey.shape
        raise ConfigError(odd.path, "<file>", f"{w} x {h} px where {views[0].path.name} is {w0} x {h0} px: the photos "
                                              "of one camera have one size")
    if len(views) < 3:
        raise ConfigError(cfg["_file"], "photos.inner_corners", f"a board of {pattern[0]} x {pattern[1]} inner corners "
                                                                f"was found in {len(views)} of {len(files)} photos "
                                                                "(a calibration needs 3)")
    res = calibrate_views(views, pattern, cfg["photos"]["model"])
    if not res.success:
        raise BenchError(f"{cfg['photos']['dir']}: the real photos' calibration failed: {res.message}")
    if verbose:
        print(f"real photos: the board in {len(views)} of {len(files)}, calibration RMS {res.rms_px:.3f} px")
    return views, res


def board_poses(res, square_m: float) -> np.ndarray:
    """``T_cam_board`` (V, 4, 4): the calibration's target poses (unit squares, origin at the first inner corner)
    in metres and moved to the simulated board's frame (origin at the pattern's outer corner, one square before)."""
    T = np.array(res.T_cam_target, float).copy()
    T[:, :3, 3] *= square_m
    return T @ homogeneous(np.eye(3), [-square_m, -square_m, 0.0])


# ------------------------------------------------------------------------------------------------ the replica


def board_errors(profile, pattern, seed: int, square_m: float) -> dict | None:
    """The printed board's geometry errors for a board of ``pattern + 1`` squares: the rig's draws
    (:func:`bench.sim.imaging.target_geometry`, board A, on a square grid of the larger side) cut to the board."""
    from bench.sim.imaging import target_geometry

    if not profile.stages:
        return None
    cols, rows = pattern[0] + 1, pattern[1] + 1
    e = target_geometry(profile, max(cols, rows), np.random.default_rng(np.random.SeedSequence([seed, 0x7A12])),
                        square_m)
    xs, ys = e["line_offsets_m"]["a"]
    return {"line_offsets_m": (xs[:cols + 1], ys[:rows + 1]), "scale": e["scale"],
            "bow_sagitta_m": e["bow_sagitta_m"]["a"], "dz_m": e["dz_m"]["a"][:rows + 1, :cols + 1],
            "black_reflectance": e["black_reflectance"]}


def render_replica(cfg, res, views, out_dir, verbose=False) -> list:
    """Render the board at every photo's pose through the simulated camera; the grey renders ``(H, W)`` uint8.

    The scene is the lab of the camera-calibration kind (:class:`~bench.scenario.camera_calibration.TableRigScene`):
    the camera stands still in the x-y table's mount and the board, a mocap body, is put at ``T_cam_board`` in front
    of it for each photo (a new board, with its own flexing, per photo when the ``handling`` stage is on)."""
    from bench.camera.presets import load_preset
    from bench.scenario.camera_calibration import TableRigScene
    from bench.sim.imaging import handling_dz
    from bench.sim.optics_presets import optics_preset
    from bench.sim.scenes.rig import planar_board
    from bench.sim.scenes.xy_table import lab_table_model

    profile = imaging(cfg)
    pattern = tuple(cfg["photos"]["inner_corners"])
    square_m = cfg["photos"]["square_mm"] * 1e-3
    seed = cfg["seed"]
    optics = optics_preset("air_webcam")
    h, w = views[0].grey.shape
    dist = np.zeros(5)
    dist[:len(np.ravel(res.dist))] = np.ravel(res.dist)
    lens = load_preset(optics.lens_camera).replace(width=int(w), height=int(h), K=np.array(res.K, float), dist=dist,
                                                   model=None, name="the photos' camera (simulated)")
    errors = board_errors(profile, pattern, seed, square_m)
    cols, rows = pattern[0] + 1, pattern[1] + 1
    table = lab_table_model(None)
    qpos = {name: vals[0] for name, vals in table.run(np.zeros((1, 3))).qpos.items()}
    greys, scene, T_world_cam = [], None, None
    try:
        for k, T_cb in enumerate(board_poses(res, square_m)):
            if scene is None or profile.on("handling"):  # a hand-held board flexes anew in every photo
                if scene is not None:
                    scene.close()
                view_errors = errors
                if profile.on("handling"):
                    flex = handling_dz(profile, max(cols, rows),
                                       np.random.default_rng(np.random.SeedSequence([seed, 0x7A14, k])), square_m)
                    view_errors = dict(errors, dz_m=errors["dz_m"] + flex[:rows + 1, :cols + 1])
                board = planar_board(rows, cols, square_m, name="board", errors=view_errors)
                scene = TableRigScene(lens, optics, table, board, cfg["camera"]["supersample"], None, z_min=0.1,
                                      imaging=profile)
                T_world_cam = scene.pose(qpos, np.eye(4))
            img, T_wc = scene.render(qpos, T_world_cam @ T_cb, seed=seed * 1000 + k)
            if not np.allclose(T_wc, T_world_cam):
                raise RuntimeError("the camera moved between views (the table stands still)")
            greys.append(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
            if cfg["outputs"]["images"]:
                ok, png = cv2.imencode(".png", greys[-1])
                atomic_write_bytes(out_dir / "renders" / f"{views[k].path.stem}.png", png.tobytes())
            if verbose:
                print(f"  {k + 1}/{len(views)}", end="", flush=True)
    finally:
        if scene is not None:
            scene.close()
    if verbose:
        print()
    return greys


def calibrate_replica(cfg, greys, real_views):
    """``(views found, calibration or None)`` of the renders, by the code that calibrated the photos."""
    from bench.camera.photo_stats import BoardView

    pattern = tuple(cfg["photos"]["inner_corners"])
    views = []
    for g, rv in zip(greys, real_views, strict=True):
        uv = detect_board(g, pattern)
        if uv is not None:
            views.append(BoardView(rv.path, g, g, uv))
    if len(views) < 3:
        return views, None
    res = calibrate_views(views, pattern, cfg["photos"]["model"])
    return views, res if res.success else None


# ------------------------------------------------------------------------------------------------ the run


def statistics(views, res, pattern) -> dict:
    return {**residual_statistics(res.residuals_px, pattern), **measure_sift_precision(views, pattern, res.K, res.dist),
            **measure_blur(views, pattern), **measure_edge_profile(views, pattern), **measure_noise(views, pattern)}


def run(cfg, out_dir, verbose=True):
    """Calibrate the photos, render and calibrate their replica, compare; write result.json and the tables (``cfg``
    from :func:`bench.scenario.runner.load_scenario`, which ran :func:`validate`)."""
    out_dir = Path(out_dir)
    pattern = tuple(cfg["photos"]["inner_corners"])
    t0 = time.perf_counter()
    real_views, real = calibrate_photos(cfg, verbose)
    real_stats = statistics(real_views, real, pattern)
    t1 = time.perf_counter()
    if verbose:
        print(f"rendering {len(real_views)} views of the replica ({cfg['camera']['imaging']} imaging) ...")
    greys = render_replica(cfg, real, real_views, out_dir, verbose)
    t2 = time.perf_counter()
    sim_views, sim = calibrate_replica(cfg, greys, real_views)
    if sim is None:
        raise BenchError(f"{cfg['name']} (seed {cfg['seed']}): the board was found in {len(sim_views)} of "
                         f"{len(greys)} renders, or their calibration failed: no replica to compare")
    sim_stats = statistics(sim_views, sim, pattern)
    metrics = {"photos": float(len(photo_files(cfg))), "real_views": float(len(real_views)),
               "sim_views": float(len(sim_views))}
    for k in STATS:
        metrics[f"real_{k}"], metrics[f"sim_{k}"] = real_stats[k], sim_stats[k]
    metrics["rms_ratio"] = sim_stats["rms_px"] / real_stats["rms_px"]
    metrics["sift_ratio"] = sim_stats["sift_plane_px"] / real_stats["sift_plane_px"]
    metrics["sim_focal_error_pct"] = 100.0 * (sim.K[0, 0] / real.K[0, 0] - 1.0)  # the replica's camera is real.K
    sim_rms = dict(zip((v.path.name for v in sim_views), sim_stats["per_view_rms_px"], strict=True))
    per_view = {"photo": [v.path.name for v in real_views], "real_rms_px": real_stats["per_view_rms_px"],
                "sim_rms_px": [sim_rms.get(v.path.name, float("nan")) for v in real_views]}
    lags = [1, 2, 3]
    corr = {"lag": lags, **{f"{src}_{d}": [(real_stats if src == "real" else sim_stats)[f"{d}_corr_lag{k}"]
                                            for k in lags] for src in ("real", "sim") for d in ("row", "col")}}
    write_table_csv(out_dir / "per_view.csv", per_view)
    write_table_csv(out_dir / "correlation.csv", corr)
    artifacts = {"per_view_csv": "per_view.csv", "correlation_csv": "correlation.csv"}
    if cfg["outputs"]["images"]:
        artifacts["renders"] = "renders"
    if cfg["outputs"]["plots"]:
        artifacts["replica_plot"] = plot_replica(per_view, corr, metrics, out_dir / "replica.png")
    timings = {"real_s": t1 - t0, "render_s": t2 - t1, "replica_s": time.perf_counter() - t2,
               "total_s": time.perf_counter() - t0}
    path = write_result(out_dir, cfg["name"], cfg["seed"], metrics, {"per_view": per_view, "correlation": corr},
                        timings, artifacts)
    if verbose:
        print(format_summary(metrics))
    return path


def plot_replica(per_view: dict, corr: dict, metrics: dict, path) -> str:
    """Per-view calibration RMS (real beside simulated) and the residual correlation along rows and columns."""
    plt = headless_pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    x = np.arange(len(per_view["photo"]))
    a.bar(x - 0.2, per_view["real_rms_px"], 0.4, label=f"real photos (RMS {metrics['real_rms_px']:.3f} px)")
    a.bar(x + 0.2, per_view["sim_rms_px"], 0.4, label=f"simulated (RMS {metrics['sim_rms_px']:.3f} px)")
    a.set_xticks(x, per_view["photo"], rotation=60, fontsize=7)
    a.set_ylabel("calibration residual RMS per view (px)")
    a.legend(fontsize=8)
    for d, c in (("row", "C0"), ("col", "C3")):
        b.plot(corr["lag"], corr[f"real_{d}"], "o-", color=c, label=f"along a {d}: real")
        b.plot(corr["lag"], corr[f"sim_{d}"], "s--", color=c, label=f"along a {d}: simulated")
    b.axhline(0, color="k", lw=0.5)
    b.set(xticks=corr["lag"], xlabel="corners apart", ylabel="correlation of residual vectors")
    b.legend(fontsize=8)
    fig.suptitle(f"The photos and their simulation, calibrated by the same code: RMS simulated / real "
                 f"{metrics['rms_ratio']:.2f}", fontsize=10)
    fig.tight_layout()
    atomic_save_figure(fig, path, dpi=110)
    return Path(path).name


def format_summary(m: dict) -> str:
    lines = [f"the board in {int(m['real_views'])} of {int(m['photos'])} photos and {int(m['sim_views'])} renders",
             f"  {'statistic':<18}{'real':>10}{'simulated':>12}"]
    lines += [f"  {k:<18}{m[f'real_{k}']:>10.3f}{m[f'sim_{k}']:>12.3f}" for k in STATS]
    lines.append(f"  RMS simulated / real {m['rms_ratio']:.2f} (issue 12: 0.7-1.3); SIFT on the plane "
                 f"{m['sift_ratio']:.2f}; the replica's focal length off by {m['sim_focal_error_pct']:+.2f} %")
    hint = processing_hint(m)
    if hint:
        lines.append(f"  {hint}")
    return "\n".join(lines)


def processing_hint(m: dict) -> str:
    """A pointer to the processing fit when the photos' pixels differ from the simulated camera's: edge spreads more
    than 25 % apart, or halos more than 10 DN apart ("" when they agree, or were not measured)."""
    try:
        er, es = m["real_edge_sigma_px"], m["sim_edge_sigma_px"]
        hr, hs = m["real_edge_undershoot_dn"], m["sim_edge_undershoot_dn"]
    except KeyError:
        return ""
    if not all(np.isfinite([er, es, hr, hs])) or er <= 0 or (0.8 <= es / er <= 1.25 and abs(hs - hr) <= 10.0):
        return ""
    return (f"the photos' pixels differ from the simulated camera's (edge spread {er:.2f} against {es:.2f} px, halo "
            f"{hr:.1f} against {hs:.1f} DN): fit its processing to them with tools/fit_camera_processing.py "
            "(docs/realistic_imaging.md, section 3.3)")
