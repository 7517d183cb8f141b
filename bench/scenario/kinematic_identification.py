"""Scenario kind ``kinematic_identification``: thesis Table 2 reproduced, then the realistic lab calibration.

Parts (each reported in ``result.json``):

1. identifiability - closed form (Eq. 21, 23, 167) vs numeric rank analysis, for O6 and for an off-axis point;
2. the thesis's experiment - true errors of Table 2, linearised simulation ``dX = J_e eps`` (Eq. 12), 100 random
   in-limit poses, no noise, linear least squares on the reduced Jacobian (Eq. 14);
3. the realistic case - exact SE(3) truth with Table 2's errors, tracker noise, iterated identification on the
   exact model, held-out accuracy on 1000 other poses;
4. a Monte Carlo of (3) over noise draws: predicted vs observed spread of the estimate;
5. observability-optimal pose selection vs random poses;
6. section 4.6: pose error of the end effector and of link 5 after calibration (Figures 36-39).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from bench.config import NonNegInt, PlotOutputs, PositiveInt, ScenarioBase, Section, Vec3, at_most, section
from bench.errors import ConfigError
from bench.fileio import csv_number, read_csv_table
from bench.robot.identifiability import closed_form_reduction, numeric_identifiability
from bench.robot.identification import identify_iterative, identify_linear
from bench.robot.jacobian import identification_jacobian
from bench.robot.kinematics import ee_position
from bench.robot.model import error_names, load_robot
from bench.robot.observability import INDICES, observability_indices, select_poses
from bench.robot.orientation import orientation_analysis
from bench.scenario.results import write_result, write_table_csv


class Truth(Section):
    errors_csv: str


class Linear(Section):
    n_poses: PositiveInt = 100


class Realistic(Section):
    n_poses: PositiveInt = 100
    n_heldout: PositiveInt = 1000
    tracker_sigma_mm: Annotated[float, Field(gt=0), at_most(50, "{v} mm is implausible; the unit is mm, not um")] = 0.05


class MonteCarlo(Section):
    seeds: NonNegInt = 200


class PoseSelection(Section):
    index: Literal[INDICES] = "O1"
    n_poses: PositiveInt = 100
    n_candidates: PositiveInt = 2000
    n_random_sets: NonNegInt = 20


class Orientation(Section):
    n_configurations: PositiveInt = 100


class Identifiability(Section):
    n_poses: PositiveInt = 60
    off_axis_point_mm: Vec3 = [50.0, 0.0, 100.0]


class Scenario(ScenarioBase):
    """A ``kinematic_identification`` scenario file."""

    robot: str = "../models/ta40.yaml"
    truth: Truth
    linear: Linear = section(Linear)
    realistic: Realistic = section(Realistic)
    monte_carlo: MonteCarlo = section(MonteCarlo)
    pose_selection: PoseSelection = section(PoseSelection)
    orientation: Orientation = section(Orientation)
    identifiability: Identifiability = section(Identifiability)
    outputs: PlotOutputs = section(PlotOutputs)


_MM = np.array([1e3, 1e3, 1e3, 1.0, 1.0, 1.0])  # SI -> thesis units (mm, rad) per kind x y z s r p


def to_thesis_units(eps):
    """SI error vector -> mm for translations, rad for rotations."""
    return np.asarray(eps) * np.tile(_MM, len(eps) // 6)


def from_thesis_units(eps):
    """mm / rad -> SI."""
    return np.asarray(eps) / np.tile(_MM, len(eps) // 6)


def load_error_table(path) -> dict:
    """Read a Table-2-style CSV (``name`` + numeric columns, mm/rad, rows in error-vector order)."""
    header, rows = read_csv_table(path)
    rows = [dict(zip(header, r, strict=True)) for r in rows]
    if not rows or "name" not in header or "full" not in header:
        raise ConfigError(path, "<header>", "expected columns 'name' and 'full'")
    names = [r["name"] for r in rows]
    expected = error_names(len(rows) // 6 if len(rows) % 6 == 0 else 7)
    if names != expected:
        bad = next((i for i, (a, b) in enumerate(zip(names, expected, strict=False)) if a != b), len(names))
        raise ConfigError(path, f"row {bad + 1}",
                          f"names must be {expected[0]}, {expected[1]}, ... {expected[-1]} in order")
    return {"name": names, **{col: np.array([csv_number(path, f"{col} (row {i + 1}, {names[i]})", r[col])
                                             for i, r in enumerate(rows)]) for col in header if col != "name"}}


def _check_pose_counts(cfg, n_params):
    """Every identification needs at least ``n_params / 3`` poses (3 equations per tracker point)."""
    need = -(-n_params // 3)
    for key in ("linear.n_poses", "realistic.n_poses", "pose_selection.n_poses"):
        sec, k = key.split(".")
        n = cfg[sec][k]
        if n < need:
            raise ConfigError(cfg["_file"], key, f"{n} poses give {3 * n} equations for {n_params} identifiable "
                                                 f"errors; need at least {need}")


def validate(cfg: dict) -> None:
    """Check every value of a loaded scenario without running it (``bench sweep`` does, per grid point)."""
    robot = load_robot(Path(cfg["_file"]).parent / cfg["robot"])
    _check_pose_counts(cfg, len(closed_form_reduction(robot).kept))


def _rms_mm(a, b):
    return float(1e3 * np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))


class _Progress:
    """A minimal stderr progress bar (silent when not verbose)."""

    def __init__(self, label, total, verbose):
        self.label, self.total, self.verbose, self.t0 = label, max(total, 1), verbose, time.perf_counter()

    def update(self, k):
        if self.verbose and sys.stderr.isatty():
            frac = k / self.total
            bar = "#" * int(30 * frac)
            print(f"\r  {self.label:<28} [{bar:<30}] {k}/{self.total} {time.perf_counter() - self.t0:5.1f}s",
                  end="", file=sys.stderr, flush=True)

    def close(self):
        if self.verbose and sys.stderr.isatty():
            print(file=sys.stderr)


def run(cfg: dict, out_dir: Path, verbose: bool = True) -> Path:
    base = Path(cfg["_file"]).parent
    robot = load_robot(base / cfg["robot"])
    table = load_error_table(base / cfg["truth"]["errors_csv"])
    if len(table["full"]) != robot.n_errors:
        raise ConfigError(base / cfg["truth"]["errors_csv"], "full",
                          f"{len(table['full'])} errors for a robot with {robot.n_errors}")
    eps_true = from_thesis_units(table["full"])
    rng = np.random.default_rng(cfg["seed"])
    metrics, timings, tables, artifacts = {}, {}, {}, {}
    t_all = time.perf_counter()

    # 1. identifiability ---------------------------------------------------------------------------------
    t0 = time.perf_counter()
    red = closed_form_reduction(robot)
    try:
        num = numeric_identifiability(robot, rng, cfg["identifiability"]["n_poses"], preferred=red.kept)
        num_free = numeric_identifiability(robot, rng, cfg["identifiability"]["n_poses"])
        off = robot.with_ee_point(np.asarray(cfg["identifiability"]["off_axis_point_mm"], dtype=float) * 1e-3)
        num_off = numeric_identifiability(off, rng, cfg["identifiability"]["n_poses"])
        red_off = closed_form_reduction(off)
    except ValueError as exc:
        key = "identifiability.n_poses" if str(exc).startswith("n_poses") else "identifiability.off_axis_point_mm"
        raise ConfigError(cfg["_file"], key, str(exc).removeprefix("n_poses: ")) from None
    metrics.update({
        "n_identifiable_closed_form": len(red.kept),
        "rank_numeric": num.rank,
        "closed_vs_numeric_same_columns": float(np.array_equal(num.kept, red.kept)),
        "closed_vs_numeric_map_max_abs_diff": float(np.abs(num.M - red.M).max()),
        "rank_numeric_off_axis_point": num_off.rank,
        "n_identifiable_closed_form_off_axis_point": len(red_off.kept),
    })
    names = error_names(robot.n + 1)
    tables["merges"] = {
        "eliminated": list(red.merged),
        "merged_into": ["; ".join(f"{k} x {v:.6g}" for k, v in red.merged[e].items()) or "(invisible)"
                        for e in red.merged],
    }
    tables["numeric_pivoted_qr_choice"] = {"kept": num_free.names}
    timings["identifiability"] = time.perf_counter() - t0

    # 2. the thesis's experiment: linear, noise-free -------------------------------------------------------
    t0 = time.perf_counter()
    q_lin = robot.random_configurations(rng, cfg["linear"]["n_poses"])
    dX = identification_jacobian(robot, q_lin) @ eps_true  # Eq. 12, one 3-vector per pose
    lin = identify_linear(robot, q_lin, ee_position(robot, q_lin) + dX, red, sigma=1.0)
    reduced_true = red.reduce(eps_true)
    if not lin.success:
        raise ConfigError(cfg["_file"], "linear.n_poses", lin.message)
    est_full = red.expand(lin.eps_dot)
    true_full = red.expand(reduced_true)
    metrics["max_abs_reduced_error_linear"] = float(np.abs(to_thesis_units(est_full - true_full)).max())
    metrics["condition_number_linear"] = lin.condition_number
    tables["table2"] = {
        "name": names,
        "full": to_thesis_units(eps_true).tolist(),
        "reduced_true": to_thesis_units(true_full).tolist(),
        "reduced_estimated": to_thesis_units(est_full).tolist(),
    }
    tables["table2_thesis"] = {"name": names, "full": table["full"].tolist(),
                               "reduced_actual": table.get("reduced_actual", np.full(42, np.nan)).tolist(),
                               "reduced_estimated": table.get("reduced_estimated", np.full(42, np.nan)).tolist()}
    timings["linear"] = time.perf_counter() - t0

    # 3. realistic: exact truth, tracker noise, iterated identification ------------------------------------
    t0 = time.perf_counter()
    sigma = cfg["realistic"]["tracker_sigma_mm"] * 1e-3
    q_id = robot.random_configurations(rng, cfg["realistic"]["n_poses"])
    q_ho = robot.random_configurations(rng, cfg["realistic"]["n_heldout"])
    p_id = ee_position(robot, q_id, eps_true)
    p_ho = ee_position(robot, q_ho, eps_true)
    metrics["heldout_rms_mm_uncalibrated"] = _rms_mm(ee_position(robot, q_ho), p_ho)
    clean = identify_iterative(robot, q_id, p_id, red, sigma=sigma)
    if not np.all(np.isfinite(clean.eps)):
        raise ConfigError(cfg["_file"], "realistic", f"noise-free identification failed: {clean.message}")
    metrics["heldout_rms_mm_noise_free_exact"] = _rms_mm(ee_position(robot, q_ho, clean.eps), p_ho)
    metrics["iterations_noise_free_exact"] = clean.iterations
    noisy_pts = p_id + rng.normal(scale=sigma, size=p_id.shape)
    t1 = time.perf_counter()
    res = identify_iterative(robot, q_id, noisy_pts, red, sigma=sigma)
    metrics["identification_s"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    identify_linear(robot, q_id, noisy_pts, red, sigma=sigma)
    metrics["identification_linear_s"] = time.perf_counter() - t1
    if not res.success:
        raise ConfigError(cfg["_file"], "realistic", f"identification failed: {res.message}")
    metrics["heldout_rms_mm_calibrated"] = _rms_mm(ee_position(robot, q_ho, res.eps), p_ho)
    # the bound: Cramér-Rao of eps_dot from the tracker noise, (G^T G / sigma^2)^-1 with G at the truth (Eq. 12-13),
    # carried to the held-out poses: RMS over them of sqrt(tr(J C J^T)) - no unbiased estimator predicts better
    G = identification_jacobian(robot, q_id, eps_true)[..., red.kept].reshape(-1, len(red.kept))
    crb = np.linalg.inv(G.T @ G) * sigma**2
    J_ho = identification_jacobian(robot, q_ho, eps_true)[..., red.kept]
    metrics["heldout_rms_bound_mm"] = float(np.sqrt(np.mean(np.einsum("nij,jk,nik->n", J_ho, crb, J_ho))) * 1e3)
    metrics["heldout_efficiency"] = metrics["heldout_rms_bound_mm"] / metrics["heldout_rms_mm_calibrated"]
    metrics.update({"residual_rms_mm": res.residual_rms * 1e3, "condition_number": res.condition_number,
                    "iterations": res.iterations})
    # the linearised thesis method on exact, noisy data, for comparison
    lin_real = identify_linear(robot, q_id, noisy_pts, red, sigma=sigma)
    metrics["heldout_rms_mm_calibrated_linear_method"] = _rms_mm(ee_position(robot, q_ho, lin_real.eps), p_ho)
    timings["realistic"] = time.perf_counter() - t0

    # 4. Monte Carlo of the realistic case -------------------------------------------------------------
    t0 = time.perf_counter()
    n_mc = cfg["monte_carlo"]["seeds"]
    if n_mc >= 2:
        est = np.empty((n_mc, len(red.kept)))
        ho = np.empty(n_mc)
        bar = _Progress("Monte Carlo", n_mc, verbose)
        for k in range(n_mc):
            mc_rng = np.random.default_rng([cfg["seed"], 1000 + k])
            r = identify_iterative(robot, q_id, p_id + mc_rng.normal(scale=sigma, size=p_id.shape), red, sigma=sigma,
                                   eps0=clean.eps)
            est[k] = r.eps_dot
            ho[k] = _rms_mm(ee_position(robot, q_ho, r.eps), p_ho)
            bar.update(k + 1)
        bar.close()
        mc_std = est.std(axis=0, ddof=1)
        ratio = mc_std / res.std
        metrics.update({"mc_seeds": n_mc, "mc_std_ratio_median": float(np.median(ratio)),
                        "mc_std_ratio_min": float(ratio.min()), "mc_std_ratio_max": float(ratio.max()),
                        "mc_heldout_rms_mm_median": float(np.median(ho)),
                        "mc_heldout_rms_mm_rms": float(np.sqrt(np.mean(ho**2)))})
        # efficiency over the noise draws: bound / RMS achieved (1 = the estimator reaches the bound)
        metrics["mc_heldout_efficiency"] = metrics["heldout_rms_bound_mm"] / metrics["mc_heldout_rms_mm_rms"]
        tables["monte_carlo"] = {"name": red.names,
                                 "predicted_std": to_thesis_units(red.expand(res.std))[red.kept].tolist(),
                                 "monte_carlo_std": to_thesis_units(red.expand(mc_std))[red.kept].tolist(),
                                 "ratio": ratio.tolist()}
    timings["monte_carlo"] = time.perf_counter() - t0

    # 5. pose selection ----------------------------------------------------------------------------------
    t0 = time.perf_counter()
    ps = cfg["pose_selection"]
    q_sel, val = select_poses(robot, red.kept, ps["n_poses"], rng, ps["index"], ps["n_candidates"])
    rand_vals, rand_ho, sel_ho = [], [], []
    for _ in range(ps["n_random_sets"]):
        q_r = robot.random_configurations(rng, ps["n_poses"])
        rand_vals.append(observability_indices(robot, q_r, red.kept)[ps["index"]])
        for qs, store in ((q_r, rand_ho), (q_sel, sel_ho)):
            pts = ee_position(robot, qs, eps_true)
            r = identify_iterative(robot, qs, pts + rng.normal(scale=sigma, size=pts.shape), red, sigma=sigma)
            store.append(_rms_mm(ee_position(robot, q_ho, r.eps), p_ho))
    metrics[f"pose_selection_{ps['index']}_selected"] = val
    if rand_vals:
        metrics[f"pose_selection_{ps['index']}_random_median"] = float(np.median(rand_vals))
        metrics["heldout_rms_mm_selected_poses_median"] = float(np.median(sel_ho))
        metrics["heldout_rms_mm_random_poses_median"] = float(np.median(rand_ho))
    timings["pose_selection"] = time.perf_counter() - t0

    # 6. section 4.6: end effector vs link 5 after calibration ------------------------------------------------
    t0 = time.perf_counter()
    q_or = robot.random_configurations(rng, cfg["orientation"]["n_configurations"])
    dev = orientation_analysis(robot, q_or, eps_true, clean.eps)
    metrics["ee_pos_err_max_mm"] = float(1e3 * np.linalg.norm(dev["ee_pos_m"], axis=-1).max())
    metrics["ee_rot_err_range_deg"] = float(np.rad2deg(np.ptp(dev["ee_rot_rad"], axis=0).max()))
    metrics["link5_rot_err_range_deg"] = float(np.rad2deg(np.ptp(dev["link5_rot_rad"], axis=0).max()))
    metrics["link5_pos_err_range_mm"] = float(1e3 * np.ptp(dev["link5_pos_m"], axis=0).max())
    for a, axis in enumerate("xyz"):
        metrics[f"link5_rot_bias_deg_{axis}"] = float(np.rad2deg(dev["link5_rot_rad"][:, a].mean()))
        metrics[f"link5_pos_bias_mm_{axis}"] = float(1e3 * dev["link5_pos_m"][:, a].mean())
    tables["orientation"] = {
        **{f"ee_pos_err_mm_{a}": (1e3 * dev["ee_pos_m"][:, i]).tolist() for i, a in enumerate("xyz")},
        **{f"ee_rot_err_deg_{a}": np.rad2deg(dev["ee_rot_rad"][:, i]).tolist() for i, a in enumerate("xyz")},
        **{f"link5_pos_err_mm_{a}": (1e3 * dev["link5_pos_m"][:, i]).tolist() for i, a in enumerate("xyz")},
        **{f"link5_rot_err_deg_{a}": np.rad2deg(dev["link5_rot_rad"][:, i]).tolist() for i, a in enumerate("xyz")},
    }
    timings["orientation"] = time.perf_counter() - t0

    # outputs --------------------------------------------------------------------------------------------
    for name in ("table2", "table2_thesis", "merges", "monte_carlo", "orientation"):
        if name in tables:
            write_table_csv(out_dir / f"{name}.csv", tables[name])
            artifacts[f"{name}_csv"] = f"{name}.csv"
    if cfg["outputs"]["plots"]:
        from bench.scenario.plots import plot_monte_carlo, plot_orientation

        artifacts["figures_36_39"] = plot_orientation(tables["orientation"], out_dir / "figures_36_39.png")
        if "monte_carlo" in tables:
            artifacts["monte_carlo_plot"] = plot_monte_carlo(tables["monte_carlo"], out_dir / "monte_carlo_std.png")
    timings["total"] = time.perf_counter() - t_all
    path = write_result(out_dir, cfg["name"], cfg["seed"], metrics, tables, timings, artifacts)
    if verbose:
        print(format_table2(tables["table2"], tables["table2_thesis"]))
        print(format_summary(metrics))
    return path


def _fmt(v):
    return f"{v: .5e}" if v != 0 else f"{0: .5e}"


def format_table2(ours: dict, thesis: dict) -> str:
    """Table 2 in the thesis's layout (mm, rad), the thesis's printed reduced values beside, mismatches marked."""
    lines = ["Table 2 - Errors from simulation (translations mm, rotations rad); '*' = printed value differs",
             f"{'Error':<6}{'eps':>14}{'actual eps_dot':>16}{'estimated eps_dot':>19}  |"
             f"{'thesis actual':>15}{'thesis estim.':>15}"]
    for i, n in enumerate(ours["name"]):
        ta, te = thesis["reduced_actual"][i], thesis["reduced_estimated"][i]
        ra = ours["reduced_true"][i]
        tol = 2e-5 * max(1.0, abs(ra)) if n[0] in "xyz" else 2e-8 + 5e-6 * abs(ra)
        mark = " *" if abs(ta - ra) > tol else "  "
        lines.append(f"{'e_' + n[0] + ',' + n[1:]:<6}{_fmt(ours['full'][i]):>14}{_fmt(ra):>16}"
                     f"{_fmt(ours['reduced_estimated'][i]):>19}  |{_fmt(ta):>15}{_fmt(te):>15}{mark}")
    return "\n".join(lines)


def format_summary(m: dict) -> str:
    keys = ["max_abs_reduced_error_linear", "heldout_rms_mm_uncalibrated", "heldout_rms_mm_calibrated",
            "heldout_rms_mm_noise_free_exact", "identification_s", "mc_std_ratio_min", "mc_std_ratio_max",
            "rank_numeric", "rank_numeric_off_axis_point", "link5_rot_err_range_deg", "ee_rot_err_range_deg"]
    return "\n".join(["Summary:"] + [f"  {k:<40} {m[k]:.6g}" for k in keys if k in m])
