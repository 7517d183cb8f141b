"""tools/imaging_ablation.py: its configurations (ideal, all on, each stage off) and the shares it tabulates."""

import importlib.util
from pathlib import Path

import pytest

from bench.sim.imaging import STAGES

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("imaging_ablation", ROOT / "tools" / "imaging_ablation.py")
ablation = importlib.util.module_from_spec(spec)
spec.loader.exec_module(ablation)


def test_configurations_switch_each_stage_off_alone():
    conf = dict(ablation.configurations())
    assert conf["ideal"] == ["camera.imaging=ideal"] and conf["all on"] == ["camera.imaging=realistic"]
    assert [k for k in conf if k.endswith(" off")] == [f"{s} off" for s in STAGES]
    assert conf["jpeg off"] == ["camera.imaging=realistic", "camera.imaging_off=[jpeg]"]
    assert ablation.SUBPIXEL not in conf  # a row of the "all on" runs, not a run of its own
    from bench.scenario.runner import load_scenario

    for label, overrides in conf.items():  # every configuration is a valid scenario
        cfg = load_scenario(ablation.SCENARIO, overrides=ablation.FIXED + overrides)
        assert cfg["camera"]["imaging_off"] == ([label[:-4]] if label.endswith(" off") else [])


def test_table_medians_and_shares(tmp_path):
    results = {"ideal": {1: {"table3_chi_mean_px": 0.01, "reproj_rms_px": 0.012}},
               "all on": {1: {"table3_chi_mean_px": 0.30, "table3_chi_subpixel_mean_px": 0.22, "reproj_rms_px": 0.27},
                          2: {"table3_chi_mean_px": 0.20, "table3_chi_subpixel_mean_px": 0.16, "reproj_rms_px": 0.25},
                          3: {"table3_chi_mean_px": 0.40, "table3_chi_subpixel_mean_px": 0.30, "reproj_rms_px": 0.29}},
               "jpeg off": {1: {"table3_chi_mean_px": 0.28, "reproj_rms_px": 0.26}, 2: {"error": "not converged"}}}
    block = ablation.table(results, [1, 2, 3], ["camera.supersample=2"])
    lines = block.splitlines()
    assert lines[0] == ablation.BEGIN and lines[-1] == ablation.END
    assert "--seeds 1 2 3 --set camera.supersample=2" in lines[1]
    row = {ln.split("|")[1].strip(): [c.strip() for c in ln.split("|")[2:-1]] for ln in lines if ln.startswith("| ")}
    assert row["all on"][:4] == ["0.300", "", "0.270", ""]  # medians
    assert row["jpeg off"][:4] == ["0.280", "+0.020", "0.260", "+0.010"]  # share = all on - off; failed seed left out
    assert row["jpeg off"][-1] == "1"
    # the extractor's share: the "all on" runs' sub-pixel chi, their other figures
    assert row[ablation.SUBPIXEL][:4] == ["0.220", "+0.080", "0.270", "+0.000"]
    assert lines.index(next(ln for ln in lines if ln.startswith(f"| {ablation.SUBPIXEL}"))) == len(lines) - 2
    doc = tmp_path / "doc.md"
    doc.write_text(f"intro\n{ablation.BEGIN}\nold\n{ablation.END}\nafter\n")
    with pytest.raises(SystemExit, match="--set: expected KEY=VALUE"):
        ablation.main(["--set", "oops", "--doc", str(doc), "--out", str(tmp_path / "o")])
