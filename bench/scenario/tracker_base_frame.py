"""Scenario kind ``tracker_base_frame``: the robot base in laser-tracker coordinates from two arcs (thesis §2.9).

The simulated campaign: a tracker at a random pose (``random_transform``) measures the TA-40's point O6 while joint 1
alone moves (arc 1) and while joint 2 alone moves (arc 2), on an arm with random generalized errors in frames 2-6.
Frames 0 and 1 carry none by default: their errors are *part of* what the arcs define as the base
(see :mod:`bench.robot.base_from_arcs`), and a separate part of the report shows exactly that.

Reported (``result.json``):

* ``tables.base_accuracy_vs_noise`` - per tracker noise ``sigma_mm`` and arc span ``span_deg``: Monte Carlo median and
  RMS of the base position / rotation error, the linearly propagated prediction, and their ratio;
* metrics at the default noise and span: ``base_pos_err_mm`` and ``base_rot_err_deg`` of one simulated campaign,
  the Monte Carlo medians, the prediction, the noise-free error, the measured DH ``a1``/``alpha1``;
* the effect of errors in frames 0 and 1: how far the arc-defined base sits from the nominal base, and how closely it
  matches the stated result ``T_tracker_base E0 Tz(y1) Rz(s1)``;
* ``base_accuracy_vs_noise.png``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field

from bench.config import (
    NonNegFloat,
    Number,
    PlotOutputs,
    PositiveFloat,
    PositiveNumber,
    ScenarioBase,
    Section,
    at_most,
    section,
)
from bench.errors import ConfigError
from bench.fileio import atomic_save_figure, headless_pyplot
from bench.geometry.transforms import homogeneous, random_transform, rot_z
from bench.robot.base_from_arcs import (
    base_frame_accuracy,
    base_frame_bound,
    base_frame_from_arcs,
    pose_deviation,
    simulate_arcs,
)
from bench.robot.kinematics import error_matrix
from bench.robot.model import load_robot, random_errors
from bench.scenario.results import pose_errors, write_result, write_table_csv

SIGMA = (Field(gt=0), at_most(50, "{v} mm is implausible for a laser tracker; the unit is mm"))


class Tracker(Section):
    position_std_m: NonNegFloat = 2.0


class Truth(Section):
    error_trans_mm: NonNegFloat = 2.0
    error_rot_deg: NonNegFloat = 1.0


class Arcs(Section):
    q_start_deg: Annotated[list[Number], Field(min_length=1)] = [-10.0, 0.0, 100.0, 20.0, 40.0, 0.0]
    n_points: Annotated[int, Field(ge=3)] = 20
    default_span_deg: PositiveFloat = 90.0
    spans_deg: Annotated[list[PositiveNumber], Field(min_length=1)] = [20.0, 40.0, 60.0, 90.0]


class Noise(Section):
    default_sigma_mm: Annotated[float, *SIGMA] = 0.05
    sigmas_mm: Annotated[list[Annotated[Number, *SIGMA]], Field(min_length=1)] = [0.01, 0.05, 0.1, 0.2]


class MonteCarlo(Section):
    trials: Annotated[int, Field(ge=2)] = 200


class Scenario(ScenarioBase):
    """A ``tracker_base_frame`` scenario file."""

    robot: str = "../models/ta40.yaml"
    tracker: Tracker = section(Tracker)
    truth: Truth = section(Truth)
    arcs: Arcs = section(Arcs)
    noise: Noise = section(Noise)
    monte_carlo: MonteCarlo = section(MonteCarlo)
    outputs: PlotOutputs = section(PlotOutputs)


def _check_values(cfg, robot):
    """The checks that need the robot (its joint count and limits); returns ``(q_start, spans, sigmas)``."""
    src = cfg["_file"]
    arcs = cfg["arcs"]
    if len(arcs["q_start_deg"]) != robot.n:
        raise ConfigError(src, "arcs.q_start_deg", f"expected {robot.n} numbers, got {len(arcs['q_start_deg'])}")
    q_start = np.deg2rad(np.asarray(arcs["q_start_deg"], float))
    bad = np.flatnonzero((q_start < robot.q_min - 1e-12) | (q_start > robot.q_max + 1e-12))
    if bad.size:
        j = int(bad[0])
        raise ConfigError(src, "arcs.q_start_deg", f"joint {j + 1} at {np.rad2deg(q_start[j]):g} deg is outside "
                                                   f"[{np.rad2deg(robot.q_min[j]):g}, {np.rad2deg(robot.q_max[j]):g}]")
    spans = [float(s) for s in arcs["spans_deg"]]
    for key, values in (("arcs.spans_deg", spans), ("arcs.default_span_deg", [arcs["default_span_deg"]])):
        for s in values:
            for j in (0, 1):  # both arcs start at q_start and turn by +span
                end = np.rad2deg(q_start[j]) + s
                if end > np.rad2deg(robot.q_max[j]) + 1e-9:
                    raise ConfigError(src, key, f"{s:g} deg from arcs.q_start_deg takes joint {j + 1} to {end:g} deg,"
                                                f" beyond its limit {np.rad2deg(robot.q_max[j]):g} deg")
    return q_start, spans, [float(s) for s in cfg["noise"]["sigmas_mm"]]


def validate(cfg: dict) -> None:
    """Check every value of a loaded scenario without running it (``bench sweep`` does, per grid point)."""
    _check_values(cfg, load_robot(Path(cfg["_file"]).parent / cfg["robot"]))


def _estimate(robot, m):
    return base_frame_from_arcs(m.arc1_tracker, m.arc2_tracker, m.q1_during_arc2, m.q1_arc1, m.q2_arc2, robot)


def _cell(robot, clean, T_true, sigma, trials, rng):
    """Monte Carlo over tracker noise for one (sigma, span) cell; linear prediction at the clean arcs."""
    args = (clean.arc1_tracker, clean.arc2_tracker, clean.q1_during_arc2, clean.q1_arc1, clean.q2_arc2, robot, sigma)
    pred = base_frame_accuracy(*args)
    bound, geometry = base_frame_bound(*args), base_frame_bound(*args, readings=False)
    pos, rot, failed = [], [], 0
    for _ in range(trials):
        r = base_frame_from_arcs(clean.arc1_tracker + rng.normal(scale=sigma, size=clean.arc1_tracker.shape),
                                 clean.arc2_tracker + rng.normal(scale=sigma, size=clean.arc2_tracker.shape),
                                 clean.q1_during_arc2, clean.q1_arc1, clean.q2_arc2, robot)
        if not r.success:
            failed += 1
            continue
        p, a = pose_errors(r.T_tracker_base, T_true)
        pos.append(p)
        rot.append(a)
    pos, rot = np.array(pos), np.array(rot)
    nan = float("nan")
    return {
        "n_trials": trials, "n_failed": failed,
        "pos_err_mm_median": float(np.median(pos)) if pos.size else nan,
        "pos_err_mm_rms": float(np.sqrt(np.mean(pos**2))) if pos.size else nan,
        "rot_err_deg_median": float(np.median(rot)) if rot.size else nan,
        "rot_err_deg_rms": float(np.sqrt(np.mean(rot**2))) if rot.size else nan,
        "predicted_pos_std_mm": 1e3 * pred.pos_std_m,
        "predicted_rot_std_deg": float(np.rad2deg(pred.rot_std_rad)),
        "pos_bound_mm": 1e3 * bound.pos_std_m, "rot_bound_deg": float(np.rad2deg(bound.rot_std_rad)),
        "pos_bound_geometry_mm": 1e3 * geometry.pos_std_m,
    }


def run(cfg: dict, out_dir: Path, verbose: bool = True) -> Path:
    robot = load_robot(Path(cfg["_file"]).parent / cfg["robot"])
    q_start, spans, sigmas = _check_values(cfg, robot)
    rng = np.random.default_rng(cfg["seed"])
    metrics, timings, tables, artifacts = {}, {}, {}, {}
    t_all = time.perf_counter()
    arcs, trials = cfg["arcs"], cfg["monte_carlo"]["trials"]
    n = arcs["n_points"]

    T_true = random_transform(rng, scale=cfg["tracker"]["position_std_m"])
    eps = random_errors(rng, robot.n + 1, cfg["truth"]["error_trans_mm"] * 1e-3,
                        np.deg2rad(cfg["truth"]["error_rot_deg"]))
    eps_01_free = eps.copy()
    eps_01_free[:12] = 0.0  # frames 0 and 1 define the base (see the module docstring)

    # 1. the default campaign: noise-free exactness and one noisy realisation ------------------------------
    t0 = time.perf_counter()
    span0, sigma0 = np.deg2rad(arcs["default_span_deg"]), cfg["noise"]["default_sigma_mm"] * 1e-3
    clean = simulate_arcs(robot, T_true, q_start, span0, span0, n, eps_01_free)
    exact = _estimate(robot, clean)
    if not exact.success:
        raise ConfigError(cfg["_file"], "arcs", f"noise-free arcs give no base frame: {exact.message}")
    metrics["base_pos_err_mm_noise_free"], metrics["base_rot_err_deg_noise_free"] = pose_errors(exact.T_tracker_base,
                                                                                            T_true)
    noisy = simulate_arcs(robot, T_true, q_start, span0, span0, n, eps_01_free, sigma0, rng)
    t1 = time.perf_counter()
    res = _estimate(robot, noisy)
    metrics["base_from_arcs_s"] = time.perf_counter() - t1
    if not res.success:
        raise ConfigError(cfg["_file"], "noise.default_sigma_mm", f"the base frame cannot be estimated: {res.message}")
    metrics["base_pos_err_mm"], metrics["base_rot_err_deg"] = pose_errors(res.T_tracker_base, T_true)
    metrics["residual_rms_mm"] = 1e3 * res.residual_rms_m
    metrics["a1_measured_mm"] = 1e3 * res.a1_measured_m
    metrics["alpha1_measured_deg"] = float(np.rad2deg(res.alpha1_measured_rad))
    metrics["arc1_radius_mm"] = 1e3 * res.circle1.radius
    metrics["arc2_radius_mm"] = 1e3 * res.circle2.radius
    acc = base_frame_accuracy(noisy.arc1_tracker, noisy.arc2_tracker, noisy.q1_during_arc2, noisy.q1_arc1,
                              noisy.q2_arc2, robot, sigma0)  # what a user would compute from the measured arcs
    metrics["predicted_pos_std_mm"] = 1e3 * acc.pos_std_m
    metrics["predicted_rot_std_deg"] = float(np.rad2deg(acc.rot_std_rad))
    default_cell = _cell(robot, clean, T_true, sigma0, trials, rng)
    metrics.update({f"base_{k}": default_cell[k] for k in ("pos_err_mm_median", "rot_err_deg_median")})
    metrics["pos_rms_over_predicted"] = default_cell["pos_err_mm_rms"] / default_cell["predicted_pos_std_mm"]
    # Cramér-Rao (base_frame_bound): with the joint readings along the arcs (all the simulation's information), and
    # from the geometry alone (what the circle fit uses); efficiency = bound / RMS over the Monte Carlo
    metrics.update({f"base_{k}": default_cell[k] for k in ("pos_bound_mm", "rot_bound_deg", "pos_bound_geometry_mm")})
    metrics["base_pos_efficiency"] = default_cell["pos_bound_mm"] / default_cell["pos_err_mm_rms"]
    metrics["base_rot_efficiency"] = default_cell["rot_bound_deg"] / default_cell["rot_err_deg_rms"]
    metrics["base_pos_efficiency_geometry"] = default_cell["pos_bound_geometry_mm"] / default_cell["pos_err_mm_rms"]
    metrics["rot_rms_over_predicted"] = default_cell["rot_err_deg_rms"] / default_cell["predicted_rot_std_deg"]
    timings["default_campaign"] = time.perf_counter() - t0

    # 2. accuracy vs tracker noise and arc span --------------------------------------------------------------
    t0 = time.perf_counter()
    cols = ["sigma_mm", "span_deg", "n_trials", "n_failed", "pos_err_mm_median", "pos_err_mm_rms",
            "rot_err_deg_median", "rot_err_deg_rms", "predicted_pos_std_mm", "predicted_rot_std_deg",
            "pos_rms_over_predicted", "pos_bound_mm", "pos_bound_geometry_mm", "rot_bound_deg"]
    table = {c: [] for c in cols}
    for span in spans:
        clean_s = simulate_arcs(robot, T_true, q_start, np.deg2rad(span), np.deg2rad(span), n, eps_01_free)
        for sigma in sigmas:
            row = _cell(robot, clean_s, T_true, sigma * 1e-3, trials, rng)
            row.update(sigma_mm=sigma, span_deg=span,
                       pos_rms_over_predicted=row["pos_err_mm_rms"] / row["predicted_pos_std_mm"])
            for c in cols:
                table[c].append(row[c])
    tables["base_accuracy_vs_noise"] = table
    timings["sweep"] = time.perf_counter() - t0

    # 3. what the arcs define when frames 0 and 1 carry errors ------------------------------------------------
    t0 = time.perf_counter()
    pert = _estimate(robot, simulate_arcs(robot, T_true, q_start, span0, span0, n, eps))
    e1 = eps[6:12]
    predicted = T_true @ error_matrix(eps[:6]) @ homogeneous(rot_z(e1[3]), [0.0, 0.0, e1[1]])
    metrics["e01_base_shift_mm"], metrics["e01_base_turn_deg"] = pose_errors(pert.T_tracker_base, T_true)
    dev = pose_deviation(pert.T_tracker_base, predicted)
    metrics["e01_vs_stated_result_mm"] = float(1e3 * np.linalg.norm(dev[:3]))
    metrics["e01_vs_stated_result_deg"] = float(np.rad2deg(np.linalg.norm(dev[3:])))
    timings["frames_0_1"] = time.perf_counter() - t0

    write_table_csv(out_dir / "base_accuracy_vs_noise.csv", table)
    artifacts["base_accuracy_vs_noise_csv"] = "base_accuracy_vs_noise.csv"
    if cfg["outputs"]["plots"]:
        artifacts["base_accuracy_plot"] = plot_accuracy(table, out_dir / "base_accuracy_vs_noise.png")
    timings["total"] = time.perf_counter() - t_all
    path = write_result(out_dir, cfg["name"], cfg["seed"], metrics, tables, timings, artifacts)
    if verbose:
        print(format_table(table))
        print(format_summary(metrics))
    return path


def plot_accuracy(table: dict, path) -> str:
    """Observed (Monte Carlo RMS, median) and predicted base errors vs tracker noise, one line per arc span."""
    plt = headless_pyplot()

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    sig, span = np.asarray(table["sigma_mm"]), np.asarray(table["span_deg"])
    panels = [("pos_err_mm", "predicted_pos_std_mm", "pos_bound_mm", "base origin error (mm)"),
              ("rot_err_deg", "predicted_rot_std_deg", "rot_bound_deg", "base rotation error (deg)")]
    for ax, (obs, pred, bound, label) in zip(axes, panels, strict=True):
        for k, s in enumerate(sorted(set(span.tolist()))):
            sel = span == s
            order = np.argsort(sig[sel])
            x = sig[sel][order]
            color = f"C{k}"
            ax.plot(x, np.asarray(table[obs + "_rms"])[sel][order], "o-", color=color, label=f"{s:g} deg: MC RMS")
            ax.plot(x, np.asarray(table[obs + "_median"])[sel][order], "s:", color=color, ms=3, lw=0.8)
            ax.plot(x, np.asarray(table[pred])[sel][order], "--", color=color, lw=1.2, label=f"{s:g} deg: predicted")
            ax.plot(x, np.asarray(table[bound])[sel][order], ":", color=color, lw=2.0, label=f"{s:g} deg: bound")
        ax.set(xscale="log", yscale="log", xlabel="tracker noise sigma per axis (mm)", ylabel=label)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7, ncol=2)
    fig.suptitle("Base frame from joint-1/joint-2 arcs (section 2.9): Monte Carlo RMS (o), median (s), "
                 "linear prediction (--), Cramér-Rao bound with the joint readings (:)", fontsize=10)
    fig.tight_layout()
    atomic_save_figure(fig, path, dpi=110)
    return Path(path).name


def format_table(t: dict) -> str:
    lines = ["Base frame from arcs: accuracy vs tracker noise and arc span (Monte Carlo vs linear prediction)",
             f"{'sigma_mm':>9}{'span_deg':>9}{'pos med mm':>12}{'pos rms mm':>12}{'pred mm':>10}"
             f"{'rot med deg':>13}{'rot rms deg':>13}{'pred deg':>10}{'failed':>8}"]
    for i in range(len(t["sigma_mm"])):
        lines.append(f"{t['sigma_mm'][i]:>9.3g}{t['span_deg'][i]:>9.3g}{t['pos_err_mm_median'][i]:>12.4g}"
                     f"{t['pos_err_mm_rms'][i]:>12.4g}{t['predicted_pos_std_mm'][i]:>10.4g}"
                     f"{t['rot_err_deg_median'][i]:>13.4g}{t['rot_err_deg_rms'][i]:>13.4g}"
                     f"{t['predicted_rot_std_deg'][i]:>10.4g}{t['n_failed'][i]:>8d}")
    return "\n".join(lines)


def format_summary(m: dict) -> str:
    keys = ["base_pos_err_mm", "base_rot_err_deg", "predicted_pos_std_mm", "predicted_rot_std_deg",
            "base_pos_err_mm_median", "base_rot_err_deg_median", "pos_rms_over_predicted", "rot_rms_over_predicted",
            "base_pos_err_mm_noise_free", "base_rot_err_deg_noise_free", "a1_measured_mm", "alpha1_measured_deg",
            "e01_base_shift_mm", "e01_vs_stated_result_mm", "base_from_arcs_s"]
    return "\n".join(["Summary:"] + [f"  {k:<32} {m[k]:.6g}" for k in keys if k in m])
