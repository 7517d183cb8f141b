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


def _vector_rows(vectors, order, name="err"):
    """Rows carrying the norm ``err_mm`` and the signed components ``err_{x,y,z}_mm`` of ``vectors[k]``."""
    def metrics(v):
        return {f"{name}_mm": float(np.linalg.norm(v)), **{f"{name}_{a}_mm": float(x) for a, x in zip("xyz", v,
                                                                                                     strict=True)}}

    return [{"seed": int(k), "metrics": metrics(vectors[k])} for k in order]


COMPONENTS = {"err_mm": ("err_x_mm", "err_y_mm", "err_z_mm")}


def test_paired_displacement_measures_each_share_exactly():
    """Errors that add (a floor and two sources): switching a source off displaces the estimate by that source's part,
    so its share is the RMS of that part over the seeds, exactly, seed order notwithstanding; the difference of mean
    squares stays beside it in the table, and the closure uses the displacements."""
    rng = np.random.default_rng(21)
    floor, a, b = rng.normal(0, 0.3, (20, 3)), rng.normal(0, 1.0, (20, 3)), rng.normal(0, 0.1, (20, 3))
    order = rng.permutation(20)
    data = {"full": _vector_rows(floor + a + b, range(20)), "a": _vector_rows(floor + b, order),
            "b": _vector_rows(floor + a, order[::-1]), "none": _vector_rows(floor, range(20))}
    table, budget, metrics = budget_from_rows(data, ["a", "b"], ["err_mm"], COMPONENTS)
    rms = [float(np.sqrt(np.mean(np.sum(v**2, axis=1)))) for v in (a, b)]
    assert metrics["budget_a_mm"] == pytest.approx(rms[0], rel=1e-12)
    assert metrics["budget_b_mm"] == pytest.approx(rms[1], rel=1e-12)
    assert budget["budget_err_mm_method"] == ["paired displacement"] * 2
    full, without = table["rms_err_mm"][0], table["rms_err_mm"][2]
    assert budget["budget_err_mm_difference"][1] == pytest.approx(np.sqrt(max(0, full**2 - without**2)), rel=1e-12)
    floor_rms = table["rms_err_mm"][-1]
    assert metrics["budget_closure_err_mm"] == pytest.approx(np.sqrt(sum(r**2 for r in rms) + floor_rms**2) / full,
                                                             rel=1e-12)
    for s, r in zip("ab", rms, strict=True):
        assert metrics[f"budget_{s}_mm_lo"] < r < metrics[f"budget_{s}_mm_hi"]


def test_paired_displacement_ranks_a_small_source_the_difference_cannot():
    """A small source (RMS 0.1) under a large one (RMS 1) over 20 seeds: the difference of mean squares cannot tell
    it from nothing (its interval reaches 0), the paired displacement's interval excludes 0 and stays within a
    factor 2 of the share; a source that changes nothing is [0, 0] either way."""
    rng = np.random.default_rng(4)
    big, small = rng.normal(0, 1.0 / np.sqrt(3), (20, 3)), rng.normal(0, 0.1 / np.sqrt(3), (20, 3))
    data = {"full": _vector_rows(big + small, range(20)), "small": _vector_rows(big, range(20)),
            "same": _vector_rows(big + small, range(20)), "none": _vector_rows(np.zeros((20, 3)), range(20))}
    _, old, _ = budget_from_rows(data, ["small", "same"], ["err_mm"])  # no components: the difference
    _, new, metrics = budget_from_rows(data, ["small", "same"], ["err_mm"], COMPONENTS)
    assert old["budget_err_mm_method"] == ["difference of mean squares"] * 2
    assert old["budget_err_mm_lo"][0] == 0.0
    share = metrics["budget_small_mm"]
    assert share / 2 < metrics["budget_small_mm_lo"] < share < metrics["budget_small_mm_hi"] < 2 * share
    assert metrics["budget_same_mm"] == metrics["budget_same_mm_lo"] == metrics["budget_same_mm_hi"] == 0.0


def test_rows_without_components_fall_back_to_the_difference():
    """Budgets of earlier runs (rows without the signed components) or a failed component: the difference of mean
    squares over the seeds that have the norm."""
    rng = np.random.default_rng(2)
    v = rng.normal(0, 1, (6, 3))
    full = _vector_rows(v, range(6))
    for r in full:
        r["metrics"]["err_y_mm"] = float("nan")  # no finite component in any full row
    data = {"full": full, "x": _vector_rows(v * 0.5, range(6)), "none": _vector_rows(np.zeros((6, 3)), range(6))}
    table, budget, metrics = budget_from_rows(data, ["x"], ["err_mm"], COMPONENTS)
    assert budget["budget_err_mm_method"] == ["difference of mean squares"]
    full_rms, without = table["rms_err_mm"][0], table["rms_err_mm"][1]
    assert metrics["budget_x_mm"] == pytest.approx(np.sqrt(full_rms**2 - without**2), rel=1e-12)


def test_variants_share_one_render_cache(tmp_path):
    """A variant's sweep links its render cache to the budget's shared one; a cache a sweep already filled itself
    (a budget resumed from an earlier version) is kept, not replaced by the link."""
    from bench.scenario.sweep import _link_render_cache

    shared = tmp_path / "budget" / ".render_cache"
    link = tmp_path / "budget" / "features" / "runs" / ".render_cache"
    _link_render_cache(link, shared)
    (link / "abc.png").write_bytes(b"x")  # what a run writes into its cache lands in the shared folder
    assert link.is_symlink() and (shared / "abc.png").read_bytes() == b"x"
    _link_render_cache(link, tmp_path / "elsewhere")  # resumed: the link stays as it is
    assert link.resolve() == shared.resolve() and not (tmp_path / "elsewhere").exists()
    own = tmp_path / "budget" / "full" / "runs" / ".render_cache"
    own.mkdir(parents=True)
    (own / "kept.png").write_bytes(b"y")
    _link_render_cache(own, shared)
    assert not own.is_symlink() and (own / "kept.png").read_bytes() == b"y"


def test_a_budget_resumed_over_runs_without_components_is_not_a_mixture():
    """Seeds run by an earlier version (no signed components) beside seeds with them: the share is the difference of
    mean squares over every seed, not a displacement over the newer seeds alone."""
    rng = np.random.default_rng(9)
    v, w = rng.normal(0, 1, (6, 3)), rng.normal(0, 0.5, (6, 3))
    full, without = _vector_rows(v + w, range(6)), _vector_rows(v, range(6))
    for r in full[:3] + without[:3]:  # seeds 0-2 by the earlier version
        for a in "xyz":
            del r["metrics"][f"err_{a}_mm"]
    data = {"full": full, "x": without, "none": _vector_rows(np.zeros((6, 3)), range(6))}
    table, budget, metrics = budget_from_rows(data, ["x"], ["err_mm"], COMPONENTS)
    assert budget["budget_err_mm_method"] == ["difference of mean squares"]
    assert metrics["budget_x_mm"] == pytest.approx(np.sqrt(max(0, table["rms_err_mm"][0] ** 2
                                                               - table["rms_err_mm"][1] ** 2)), rel=1e-12)
