"""FIGAROH and this project on the same real TIAGo session, side by side (``make benchmark``; issue 16).

Data: ``../shared/data/tiago_mocap/`` beside the repository (37 static postures of a TIAGo arm measured by a Qualisys
motion-capture system; see its PROVENANCE.md) or ``--session CSV``. Nominal model: ``tiago.urdf`` of the
``example-robot-data`` package, found in the installed package at run time (never copied here). Both need the
optional dependency group: ``pip install -e ".[figaroh]"``.

Methods (all from the URDF's ``universe``/``base_footprint`` to ``wrist_ft_tool_link``, marker 1 = ``x1, y1, z1``,
the mocap-to-base transform and the marker offset estimated):

* FIGAROH 1.0.2 ``full_params`` (its TIAGo example's default model: 6 placement errors per joint, QR-reduced to the
  identifiable ones, plus base and tip frames; Levenberg-Marquardt on the position residuals, its outlier loop).
* this project (``bench.robot.marker_calibration``): ``reduced`` (hard elimination, as FIGAROH), ``prior`` (all
  errors, 2 mm / 1 deg Gaussian prior), ``prior + compliance`` (the CLI's default: joint compliance under gravity),
  and the same fitted to all four points of the marker plate (its geometry estimated; the error still scored on
  marker 1).

Protocol: leave-one-posture-out cross-validation (each of the 37 postures predicted by a model fitted, from
scratch, on the other 36; everything re-estimated per fold, including each method's own parameter selection); the
position error of marker 1 on the left-out posture; RMS over the 37. Also the fitted RMS on all 37 and the time of
one fit on all 37 postures.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.robot.marker_calibration import identify, parse_points, predict, read_measurements  # noqa: E402
from bench.robot.urdf import load_urdf_chain  # noqa: E402

SESSION = ROOT.parent / "shared" / "data" / "tiago_mocap" / "qualisys_2021-11-30_static_postures.csv"
JOINTS = ["torso_lift_joint"] + [f"arm_{i}_joint" for i in range(1, 8)]
TIP = "wrist_ft_tool_link"
OURS = {"ours: reduced": {"model": "reduced"}, "ours: prior": {"model": "prior"},
        "ours: prior + compliance": {"model": "prior", "compliance": True},
        "ours: plate, prior + comp.": {"model": "prior", "compliance": True, "markers": 4}}
PLATE = ["x1,y1,z1", "x2,y2,z2", "x3,y3,z3", "x4,y4,z4"]
FIGAROH_CONFIG = """
robot:
  name: "tiago"
  properties:
    joints:
      active_joints: {joints}
tasks:
  calibration:
    enabled: true
    parameters:
      calibration_level: "full_params"
      include_non_geometric: false
      outlier_threshold: 0.05
    kinematics:
      base_frame: "universe"
      tool_frame: "{tip}"
    measurements:
      markers:
        - name: "marker_1"
          reference_joint: "arm_7_joint"
          measurable_dof: [true, true, true, false, false, false]
      poses:
        base_pose: [0.0908, 0.08, 0.0, -1.57, 0.0, 0.0]
        tool_pose: [0.2163, 0.03484, 0.004, 0.0, -1.57, -1.57]
    data:
      source_file: "{data}"
      number_of_samples: {n}
"""


def tiago_urdf() -> Path:
    """``tiago.urdf`` inside the installed ``example-robot-data`` distribution."""
    from importlib import metadata

    try:
        files = metadata.files("example-robot-data") or []
    except metadata.PackageNotFoundError:
        raise SystemExit("example-robot-data is not installed: pip install -e '.[figaroh]'") from None
    for f in files:
        if str(f).endswith("tiago_description/robots/tiago.urdf"):
            return Path(f.locate()).resolve()
    raise SystemExit("example-robot-data has no tiago_description/robots/tiago.urdf")


def ours(urdf: Path, session: Path) -> dict:
    chain = load_urdf_chain(urdf, "base_footprint", TIP)
    out = {}
    for label, kw in OURS.items():
        kw = dict(kw)
        k = kw.pop("markers", 1)
        meas = read_measurements(session, chain, parse_points(PLATE[:k]), "m", "rad")
        m = len(meas.q)
        t0 = time.perf_counter()
        full = identify(chain, meas, weights="none", **kw)
        t_fit = time.perf_counter() - t0
        errs = []
        for i in range(m):
            cal = identify(chain, meas.subset([j for j in range(m) if j != i]), weights="none", **kw)
            p = predict(chain, meas.q[i: i + 1], cal.eps, cal.T_meas_base, cal.U, cal.compliance)
            errs.append(float(np.linalg.norm(p[0, 0] - meas.P[i, 0])))
        n_par = 6 + 3 * k + (len(full.kept) if kw["model"] == "reduced" else chain.n_errors) + len(full.compliance)
        out[label] = {"fitted_rms_mm": float(np.sqrt(np.mean(full.residuals[:, 0] ** 2)) * 1e3),  # marker 1
                      "cv_rms_mm": float(np.sqrt(np.mean(np.square(errs))) * 1e3),
                      "cv_errors_mm": [e * 1e3 for e in errs], "n_parameters": n_par, "fit_s": t_fit,
                      "cv_s": time.perf_counter() - t0 - t_fit}
    return out


def run_figaroh(urdf: Path, session: Path) -> dict:
    """FIGAROH's ``BaseCalibration`` with the TIAGo example's model (config written here, not copied)."""
    import pandas as pd
    import pinocchio as pin
    from figaroh.calibration.base_calibration import BaseCalibration
    from figaroh.calibration.calibration_tools import calc_updated_fkm
    from figaroh.tools.load_robot import load_robot

    logging.disable(logging.WARNING)

    class Calibration(BaseCalibration):
        def cost_function(self, var):  # the TIAGo example's cost: position residuals (no regularisation)
            return self.PEE_measured - calc_updated_fkm(self.model, self.data, var, self.q_measured,
                                                        self.calib_config)

    df = pd.read_csv(session)
    tmp = Path(tempfile.mkdtemp(prefix="figaroh_cfg_"))
    cfg = tmp / "tiago.yaml"
    cfg.write_text(FIGAROH_CONFIG.format(joints=json.dumps(JOINTS), tip=TIP, data=session.resolve(), n=len(df)))

    def fit(del_list):
        # package:// mesh paths resolve against the share/ folder holding example-robot-data (FIGAROH loads meshes)
        robot = load_robot(str(urdf), package_dirs=str(urdf.parents[4]), load_by_urdf=True)
        c = Calibration(robot, str(cfg), del_list=del_list)
        c.calib_config["known_baseframe"] = False
        c.calib_config["known_tipframe"] = False
        with contextlib.redirect_stdout(io.StringIO()):
            c.initialize()
            c.solve(plotting=False, enable_logging=False, html_report=False)
        return c

    def errors(c, rows):
        q = np.tile(pin.neutral(c.model), (len(rows), 1))
        for j in JOINTS:
            q[:, c.model.joints[c.model.getJointId(j)].idx_q] = df[j].to_numpy()[rows]
        pred = calc_updated_fkm(c.model, c.data, c.LM_result.x, q, dict(c.calib_config, NbSample=len(rows)))
        return np.linalg.norm(pred.reshape(3, -1).T - df[["x1", "y1", "z1"]].to_numpy()[rows], axis=1)

    t0 = time.perf_counter()
    full = fit([])
    t_fit = time.perf_counter() - t0
    fitted = errors(full, np.arange(len(df)))
    cv = [float(errors(fit([i]), np.array([i]))[0]) for i in range(len(df))]
    return {"FIGAROH full_params": {
        "fitted_rms_mm": float(np.sqrt(np.mean(fitted**2)) * 1e3),
        "cv_rms_mm": float(np.sqrt(np.mean(np.square(cv))) * 1e3), "cv_errors_mm": [e * 1e3 for e in cv],
        "n_parameters": len(full.calib_config["param_name"]), "fit_s": t_fit, "cv_s": time.perf_counter() - t0 - t_fit,
        "version": __import__("importlib.metadata").metadata.version("figaroh")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--session", default=str(SESSION), help="mocap session CSV (default: ../shared/data/...)")
    ap.add_argument("--out", default="runs/figaroh_compare.json")
    args = ap.parse_args(argv)
    session = Path(args.session)
    if not session.is_file():
        print(f"figaroh_compare: {session} not found (the TIAGo session lives in ../shared/data/tiago_mocap/)",
              file=sys.stderr)
        return 2
    try:
        import figaroh  # noqa: F401
    except ImportError:
        print("figaroh_compare: FIGAROH is not installed: pip install -e '.[figaroh]'", file=sys.stderr)
        return 2
    urdf = tiago_urdf()
    res = {**run_figaroh(urdf, session), **ours(urdf, session)}
    ref = res["FIGAROH full_params"]["cv_rms_mm"]
    print(f"TIAGo session {session.name}: 37 postures, marker 1; protocol: leave-one-posture-out (each posture "
          "predicted by a fit on the other 36)")
    print(f"{'method':<28}{'params':>7}{'fitted RMS mm':>15}{'CV RMS mm':>11}{'CV / FIGAROH':>14}{'fit s':>8}"
          f"{'CV s':>8}")
    for label, r in res.items():
        print(f"{label:<28}{r['n_parameters']:>7}{r['fitted_rms_mm']:>15.3f}{r['cv_rms_mm']:>11.3f}"
              f"{r['cv_rms_mm'] / ref:>14.2f}{r['fit_s']:>8.2f}{r['cv_s']:>8.1f}")
    doc = {"session": str(session), "urdf": str(urdf), "protocol": "leave-one-posture-out, marker 1, RMS of the 3D "
           "error over the left-out postures", "methods": res,
           "cv_ratio_ours_default_over_figaroh": res["ours: prior + compliance"]["cv_rms_mm"] / ref}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
