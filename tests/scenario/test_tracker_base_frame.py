import json
from pathlib import Path

import numpy as np
import pytest

from bench.errors import ConfigError
from bench.scenario.metrics import check_metrics
from bench.scenario.runner import load_scenario, run_scenario_file

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "tracker_base_frame.yaml"
SMOKE = ["monte_carlo.trials=60", "noise.sigmas_mm=[0.05]", "arcs.spans_deg=[30, 90]", "arcs.n_points=15"]


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("tracker_base_frame")
    path = run_scenario_file(SCENARIO, out=out, overrides=SMOKE, verbose=False)
    return out, json.loads(Path(path).read_text())


def test_result_contract(smoke):
    out, res = smoke
    assert set(res) == {"scenario", "seed", "metrics", "tables", "timings_s", "artifacts"}
    assert res["scenario"] == "tracker_base_frame" and res["seed"] == 3
    assert check_metrics("tracker_base_frame", res["metrics"]) == ([], [])  # (undeclared, missing)
    t = res["tables"]["base_accuracy_vs_noise"]
    for col in ("sigma_mm", "span_deg", "pos_err_mm_median", "rot_err_deg_median", "predicted_pos_std_mm"):
        assert len(t[col]) == 2
    assert t["span_deg"] == [30.0, 90.0] and t["n_failed"] == [0, 0]
    assert (out / res["artifacts"]["base_accuracy_plot"]).stat().st_size > 10_000
    assert (out / res["artifacts"]["base_accuracy_vs_noise_csv"]).is_file()


def test_accuracy(smoke):
    m, t = smoke[1]["metrics"], smoke[1]["tables"]["base_accuracy_vs_noise"]
    assert m["base_pos_err_mm_noise_free"] <= 1e-6 and m["base_rot_err_deg_noise_free"] <= np.rad2deg(1e-9)
    # sigma = 0.05 mm, 90 deg arcs of 15 points: one campaign within 3x the predicted RMS, MC RMS within 25 %
    assert m["base_pos_err_mm"] < 3 * m["predicted_pos_std_mm"] < 1.0
    assert m["base_rot_err_deg"] < 3 * m["predicted_rot_std_deg"] < 0.02
    assert 0.75 < m["pos_rms_over_predicted"] < 1.25 and 0.75 < m["rot_rms_over_predicted"] < 1.25
    assert all(0.75 < r < 1.25 for r in t["pos_rms_over_predicted"])
    assert t["predicted_pos_std_mm"][0] > 3 * t["predicted_pos_std_mm"][1]  # 30 deg arcs are much worse than 90
    assert abs(m["a1_measured_mm"] - 115.0) < 5 * m["predicted_pos_std_mm"]
    assert abs(m["alpha1_measured_deg"] - 90.0) < 5 * m["predicted_rot_std_deg"]
    # errors in frames 0-1 move the base by mm; the stated result T E0 Tz(y1) Rz(s1) holds to second order
    assert m["e01_base_shift_mm"] > 0.5 and m["e01_vs_stated_result_mm"] < 0.05 * m["e01_base_shift_mm"]


@pytest.mark.parametrize(
    "override, field",
    [
        ("noise.sigma_mm=0.1", "noise.sigma_mm"),
        ("noise.sigmas_mm=[0.05, -0.05]", "noise.sigmas_mm"),
        ("noise.default_sigma_mm=-0.05", "noise.default_sigma_mm"),
        ("noise.sigmas_mm=[50000]", "noise.sigmas_mm"),
        ("arcs.spans_deg=[20, 120]", "arcs.spans_deg"),
        ("arcs.n_points=2", "arcs.n_points"),
        ("arcs.q_start_deg=[0, 0, 90]", "arcs.q_start_deg"),
        ("arcs.q_start_deg=[-30, 0, 100, 0, 0, 0]", "arcs.q_start_deg"),
        ("monte_carlo.trials=1", "monte_carlo.trials"),
    ],
)
def test_bad_values_name_the_field(override, field, tmp_path):
    with pytest.raises(ConfigError) as info:
        run_scenario_file(SCENARIO, out=tmp_path, overrides=[override], verbose=False)
    assert info.value.field == field and "\n" not in str(info.value)
    assert not (tmp_path / "result.json").exists()


def test_unknown_key_suggests_the_right_one():
    with pytest.raises(ConfigError, match="did you mean 'noise.sigmas_mm'"):
        load_scenario(SCENARIO, overrides=["noise.sigmas_m=[0.1]"])
