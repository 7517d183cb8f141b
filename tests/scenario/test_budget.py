"""bench budget: the quadrature arithmetic, exactly, and a kind without error sources refused in one line."""

from pathlib import Path

import numpy as np
import pytest

from bench.errors import ConfigError
from bench.scenario.budget import budget_from_rows, run_budget

ROOT = Path(__file__).resolve().parents[2]


def _rows(values, metric="err_mm"):
    return [{"metrics": {metric: v}} for v in values]


def test_independent_sources_add_in_quadrature():
    """Two independent sources of RMS 3 and 4: all real gives RMS 5; switching one off leaves the other."""
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=20000), rng.normal(size=20000)
    a, b = 3 * a / np.sqrt(np.mean(a**2)), 4 * b / np.sqrt(np.mean(b**2))
    b -= a * np.mean(a * b) / np.mean(a * a)  # exactly uncorrelated samples
    b *= 4 / np.sqrt(np.mean(b**2))
    rows = {"full": _rows(a + b), "x": _rows(b), "y": _rows(a), "none": _rows(np.zeros(3))}
    table, budget, metrics = budget_from_rows(rows, ["x", "y"], ["err_mm"])
    assert table["rms_err_mm"][0] == pytest.approx(5.0, rel=1e-12)
    assert metrics["budget_x_mm"] == pytest.approx(3.0, rel=1e-12)  # what switching x off removed
    assert metrics["budget_y_mm"] == pytest.approx(4.0, rel=1e-12)
    assert metrics["budget_quadrature_sum_err_mm"] == pytest.approx(5.0, rel=1e-12)
    assert metrics["rms_floor_err_mm"] == 0.0 and budget["source"] == ["x", "y"]
    assert metrics["budget_closure_err_mm"] == pytest.approx(1.0, rel=1e-12)  # it adds up
    rows["y"] = _rows(a + b)  # a source whose switching off changes nothing: the budget does not close
    _, _, metrics = budget_from_rows(rows, ["x", "y"], ["err_mm"])
    assert metrics["budget_closure_err_mm"] == pytest.approx(0.6, rel=1e-12)


def test_a_source_that_does_not_matter_gets_zero_and_failed_runs_are_skipped():
    rows = {"full": _rows([1.0, 1.0, None]), "x": _rows([1.0, 1.0, float("nan")]), "none": _rows([0.0])}
    _, _, metrics = budget_from_rows(rows, ["x"], ["err_mm"])
    assert metrics["budget_x_mm"] == 0.0  # never negative, even if switching x off made it no better


def test_kind_without_sources_is_a_one_line_error(tmp_path):
    with pytest.raises(ConfigError, match="declares no error sources to budget"):
        run_budget(ROOT / "scenarios" / "tracker_base_frame.yaml", [0], tmp_path / "b", progress=False)
    assert not (tmp_path / "b").exists()


def test_paired_bootstrap_interval():
    """The 90 % interval pairs the variants by seed: a source that changes nothing has [0, 0] even when the seeds'
    errors scatter widely (an unpaired resampling would not); a source that removes a known share brackets it."""
    rng = np.random.default_rng(8)
    base = rng.lognormal(0, 1, 40)
    extra = rng.normal(0, 0.5, 40)
    seeds = list(rng.permutation(40))  # rows in any order: pairing is by seed, not by position

    def rows(values, order):
        return [{"seed": int(k), "metrics": {"err_mm": float(values[k])}} for k in order]

    full = rows(np.sqrt(base**2 + extra**2), range(40))
    data = {"full": full, "same": rows(np.sqrt(base**2 + extra**2), seeds), "x": rows(base, seeds),
            "none": rows(np.zeros(40), range(40))}
    _, budget, metrics = budget_from_rows(data, ["same", "x"], ["err_mm"])
    assert metrics["budget_same_mm"] == 0.0
    assert metrics["budget_same_mm_lo"] == 0.0 and metrics["budget_same_mm_hi"] == 0.0
    truth = float(np.sqrt(np.mean(extra**2)))
    assert metrics["budget_x_mm"] == pytest.approx(truth, rel=1e-12)
    assert metrics["budget_x_mm_lo"] < truth < metrics["budget_x_mm_hi"]
    assert budget["budget_err_mm_lo"][1] == metrics["budget_x_mm_lo"]
