"""Issue 17.3: every value is checked before anything renders or a store is created; a refusal leaves nothing."""

from pathlib import Path

import pytest

from bench.cli import main
from bench.errors import BenchError
from bench.scenario.sweep import run_sweep

SCEN = Path(__file__).resolve().parents[1] / "scenarios"


def _refused(capsys, argv, pattern):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("bench: error: ") and err.count("\n") == 0 and pattern in err, err


@pytest.mark.parametrize("extra, pattern", [
    (["--seed", "-1"], "--seed: expected a non-negative integer, got -1"),
    (["--set", "lab.tracker_poses=3"], "lab.tracker_poses: 3 poses give 9 equations"),
    (["--set", "encoders.resolution_deg=-0.001"], "encoders.resolution_deg: must be >= 0 deg"),
])
def test_sim_render_refuses_before_rendering(tmp_path, capsys, monkeypatch, extra, pattern):
    import bench.scenario.in_situ as kind

    monkeypatch.setattr(kind, "render", lambda *a, **k: pytest.fail("rendered before the refusal"))
    _refused(capsys, ["sim", "render", str(SCEN / "ta40_in_situ_manifold.yaml"), "--out", str(tmp_path / "ds"),
                      *extra], pattern)
    assert list(tmp_path.iterdir()) == []


def test_locate_negative_seed(tmp_path, capsys):
    _refused(capsys, ["locate", str(tmp_path), "--seed", "-2", "--out", str(tmp_path / "o")],
             "--seed: expected a non-negative integer, got -2")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("seeds, workers, backend, address, pattern", [
    ([-5], None, "local", None, "--seed: expected a non-negative integer"),
    ([0], -1, "local", None, "--workers: must be >= 1"),
    ([0], 0, "local", None, "--workers: must be >= 1"),
    ([], None, "local", None, "--seeds: must be >= 1"),
    ([0], None, "local", "10.0.0.1:6379", "add --backend ray"),
    ([0], 2, "ray", None, "--workers: the local backend's"),
])
def test_sweep_api_refuses_before_the_store(tmp_path, seeds, workers, backend, address, pattern):
    with pytest.raises(BenchError, match=pattern.replace("+", r"\+")):
        run_sweep(SCEN / "tracker_base_frame.yaml", [], seeds, tmp_path / "sw", backend, address, workers,
                  progress=False)
    assert list(tmp_path.iterdir()) == []


def test_in_situ_summary_says_why_render_fps_is_missing():
    """Issue 17 (small things): a run whose views all came from the render cache printed ``render_fps nan``."""
    from bench.scenario.in_situ import summary_lines

    warm = summary_lines({"base_pos_err_mm": 0.5, "views_rendered": 0.0})
    assert not any("nan" in line for line in warm)
    assert any(line.split()[0] == "render_fps" and "render cache" in line for line in warm)
    cold = summary_lines({"base_pos_err_mm": 0.5, "render_fps": 3.25, "views_rendered": 12.0})
    assert "3.25" in next(line for line in cold if line.split()[0] == "render_fps")


def test_in_situ_summary_states_the_integrity_verdict():
    """``bench run`` of the in-situ kind prints the localisation's verdict and protection levels beside its errors."""
    from bench.scenario.in_situ import integrity_lines

    lines = integrity_lines({"integrity": "warning", "integrity_reasons": ["protection radius 8.2 mm exceeds 3 mm"],
                             "protection_radius_mm": 8.22, "protection_angle_deg": 0.276})
    assert lines == ["integrity: WARNING (protection radius 8.22 mm, angle 0.276 deg)",
                     "  - protection radius 8.2 mm exceeds 3 mm"]
    refused = integrity_lines({"integrity": "refused", "integrity_reasons": ["swapped"],
                               "protection_radius_mm": float("nan"), "protection_angle_deg": float("nan")})
    assert refused[0] == "integrity: REFUSED"
