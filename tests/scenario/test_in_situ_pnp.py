"""The in-situ kind with PnP of one locate view (``pipeline.locate: pnp``): a smoke run whose bound, floor and Monte
Carlo follow the single-view localisation, and the combinations that are refused in one line. (A file of its own so
that the test workers run it beside the two-view smoke runs of test_in_situ.py.)"""

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco")

from bench.errors import ConfigError  # noqa: E402
from bench.scenario.in_situ import validate  # noqa: E402
from bench.scenario.metrics import check_metrics  # noqa: E402
from bench.scenario.runner import load_scenario, run_scenario_file  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "ta40_in_situ_manifold.yaml"
SMOKE = ["camera.supersample=1", "lab.rig_views=7", "lab.tracker_poses=60", "outputs.cache=false",
         "survey.offsets_mm=[[130, 0], [-130, 0], [0, 130], [0, -130]]", "bound.mc_trials=6", "camera.imaging=ideal",
         "camera.preset=air_webcam", "outputs.rerun=false"]


def test_pnp_run_reports_its_own_bound(tmp_path):
    """One locate view: the bound counts the map's views and the one locate view (fewer observations than the
    two-view solve's bound on the same dataset would), the floor of PnP through a central lens is ~0, and the scored
    error is the PnP estimate's."""
    path = run_scenario_file(SCENARIO, out=tmp_path / "run", seed=2, verbose=False, quiet=True,
                             overrides=SMOKE + ["pipeline.locate=pnp", "pipeline.refine=none"])
    res = json.loads(Path(path).read_text())
    m = res["metrics"]
    assert check_metrics("in_situ", m) == ([], [])  # (undeclared, missing)
    assert np.isfinite(m["base_pos_err_mm"]) and m["base_pos_err_mm"] < 20
    assert 0 < m["base_pos_crb_mm"] <= m["base_pos_bound_mm"] and 0 < m["base_rot_crb_deg"]
    assert m["base_pos_floor_mm"] < 1e-3  # air, ideal imaging: the central model is exact, PnP exact on exact data
    assert np.isfinite(m["base_pos_bound_mc_mm"]) and "base_pos_crb_mc_mm" not in m
    assert m["keypoint_locate_points"] > 0 and np.isfinite(m["keypoint_locate_ratio"])
    locate = json.loads((tmp_path / "run" / "locate.json").read_text())
    assert "PnP" in locate["message"]
    # the map's observations plus one per inlier of the single locate view
    assert m["bound_observations"] >= m["inliers"] and m["bound_observations"] > m["map_points"]


def test_pnp_combinations_refused_in_one_line():
    with pytest.raises(ConfigError, match=r"pipeline\.locate: pnp refines its own pose"):
        load_scenario(SCENARIO, overrides=["pipeline.locate=pnp"])  # the scenario's refine: joints
    with pytest.raises(ConfigError, match=r"bound\.ml_trials: the Monte Carlo of refine 'joints'"):
        validate(load_scenario(SCENARIO, overrides=["pipeline.locate=pnp", "pipeline.refine=none",
                                                    "bound.ml_trials=4"]))
    with pytest.raises(ConfigError, match="expected two_view or pnp"):
        load_scenario(SCENARIO, overrides=["pipeline.locate=three_view"])
