"""tools/keypoint_shuffle.py's variants of a run's keypoint residuals, on synthetic residuals: what each keeps and
what it breaks (each view's multiset of residuals, each point's residual vector over its views, a smooth field)."""

import importlib.util
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("keypoint_shuffle", ROOT / "tools" / "keypoint_shuffle.py")
tool = importlib.util.module_from_spec(spec)
sys.modules["keypoint_shuffle"] = tool
spec.loader.exec_module(tool)


def _synthetic(rng, V=5, M=300, field=None):
    P = rng.uniform([0, 0], [640, 480], (V, M, 2))
    vis = rng.random((V, M)) < 0.7
    vis[:2] = True  # every point in two views at least
    resid = rng.normal(0.0, 0.1, (V, M, 2))
    if field is not None:
        resid = field(P)
    resid[~vis] = np.nan
    return {"P": P, "resid": resid, "vis": vis}


def test_each_variant_keeps_what_it_says():
    rng = np.random.default_rng(5)
    S = _synthetic(rng)
    P, r, vis = S["P"], S["resid"], S["vis"]
    out = tool.variants(S, np.random.default_rng(1))
    assert set(out) == set(tool.VARIANTS)
    np.testing.assert_array_equal(out["exact"], P)
    for k in range(len(vis)):  # obs_shuffle: each view's residuals, permuted among the points it sees
        got, want = (out["obs_shuffle"][k] - P[k])[vis[k]], r[k][vis[k]]
        np.testing.assert_allclose(np.sort(got, axis=0), np.sort(want, axis=0), atol=1e-9)
        assert not np.allclose(got, want)
    # track_swap: every point's residual vector over its views is some point's of the same pattern
    got = out["track_swap"] - P
    want = {tuple(np.round(np.nan_to_num(r[:, j]).ravel(), 9)) for j in range(vis.shape[1])}
    assert all(tuple(np.round(np.nan_to_num(got[:, j]).ravel(), 9)) in want for j in range(vis.shape[1]))
    assert not np.allclose(np.nan_to_num(got), np.nan_to_num(r))
    w = (out["white"] - P)[vis]  # white: Gaussian of each view's robust sigma (0.1 px here)
    assert abs(np.std(w) - 0.1) < 0.01
    assert np.all(np.isnan(out["white"][~vis]))


def test_a_smooth_field_is_kept_exactly_by_the_smooth_variant_and_lost_by_the_shuffle():
    rng = np.random.default_rng(6)

    def cubic(P):  # a cubic field in the pixel, per view
        u, v = (P - P.mean(axis=1, keepdims=True)).transpose(2, 0, 1) / 100.0
        return np.stack([0.05 * u - 0.02 * u * v + 0.01 * v**3, 0.03 + 0.02 * u**2 * v], axis=-1)

    S = _synthetic(rng, field=cubic)
    P, r, vis = S["P"], S["resid"], S["vis"]
    # the fit is about each view's observed points' mean pixel: the same field, re-expressed - exact on them
    out = tool.variants(S, np.random.default_rng(2))
    np.testing.assert_allclose((out["smooth"] - P)[vis], r[vis], atol=1e-9)
    assert np.sqrt(np.mean(((out["obs_shuffle"] - P)[vis] - r[vis]) ** 2)) > 0.01
