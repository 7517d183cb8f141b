"""tools/keypoint_consistency.py's measurements of the keypoints' error correlation between views, on synthetic
tracks of a plane seen by a pin-hole camera moving along a line (the x-y table's kind of campaign): the true
projector's inverse, independent errors giving the null correlation, errors shared by nearby views recognised as
such on the surface (no triangulation), and a straight-line drift with the camera recovered."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.camera.presets import load_preset
from bench.geometry.transforms import homogeneous, rot_y

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("keypoint_consistency", ROOT / "tools" / "keypoint_consistency.py")
tool = importlib.util.module_from_spec(spec)
sys.modules["keypoint_consistency"] = tool
spec.loader.exec_module(tool)

PLANE_Z = 0.75
NAMES = [f"p{k:02d}" for k in range(1, 22)]


class _Plane:
    """Ray casting onto the plane z = PLANE_Z (the interface of bench.scenario.scene_points.SceneRays)."""

    def first_hits(self, origins, directions):
        s = (PLANE_Z - origins[:, 2]) / directions[:, 2]
        return np.where((s > 0)[:, None], origins + s[:, None] * directions, np.nan)


def _campaign(rng, errors, n_tracks=300, sigma=0.08):
    """21 cameras 10 mm apart along x, turned +-8 deg about y, looking at points of the plane; ``errors(c, rng)``
    draws a track's pixel errors (V, 2) for camera centres ``c (V, 3)``. Returns tracks as the tool builds them."""
    cam = load_preset("air_webcam")
    T = {n: homogeneous(rot_y(np.deg2rad(8.0 * (k - 10) / 10)), [0.01 * (k - 10), 0.0, 0.0])
         for k, n in enumerate(NAMES)}
    c = np.array([T[n][:3, 3] for n in NAMES])
    tracks = {}
    for i in range(n_tracks):
        X = np.r_[rng.uniform(-0.12, 0.12, 2), PLANE_Z]
        uv = np.array([cam.project((np.linalg.inv(T[n]) @ np.r_[X, 1.0])[:3]) for n in NAMES])
        tracks[i] = dict(zip(NAMES, uv + errors(c, rng) * sigma, strict=True))
    return tracks, T, cam


def _independent(c, rng):
    return rng.normal(size=(len(c), 2))


def _shared(c, rng, w=0.7, length=0.03):
    D = np.linalg.norm(c[:, None] - c[None], axis=-1)
    return np.linalg.cholesky((1 - w) * np.eye(len(c)) + w * np.exp(-D / length)) @ rng.normal(size=(len(c), 2))


def _drift(c, rng):
    return np.outer(c[:, 0] - c[:, 0].mean(), [20.0, -10.0]) + 0.01 * rng.normal(size=(len(c), 2))


def test_the_true_projector_is_inverted():
    cam = load_preset("air_webcam")
    prism = (5e-4, 0.0, -5e-4, 0.0)

    def project(p):  # the lens, then a thin-prism warp as the realistic profile adds it
        uv = cam.project(p)
        x, y = (uv[..., 0] - cam.K[0, 2]) / cam.K[0, 0], (uv[..., 1] - cam.K[1, 2]) / cam.K[1, 1]
        r2 = x**2 + y**2
        return uv + np.stack([prism[0] * r2 * cam.K[0, 0], prism[2] * r2 * cam.K[1, 1]], axis=-1)

    uv = np.random.default_rng(0).uniform((0, 0), (639, 479), (200, 2))
    d = tool._unproject(uv, cam, project)
    assert np.abs(project(d) - uv).max() < 1e-6 and np.allclose(np.linalg.norm(d, axis=1), 1.0)


@pytest.mark.parametrize("errors", ["independent", "shared"])
def test_surface_correlation_sees_errors_nearby_views_share(errors):
    tracks, T, cam = _campaign(np.random.default_rng(5), {"independent": _independent, "shared": _shared}[errors])
    pairs, drift = tool.surface_pairs(tracks, T, cam, cam.project, _Plane(), "p11")
    near = tool.surface_table(pairs)[0]
    assert near["to_mm"] == 20.0 and abs(near["sigma_x_px"] / 0.08 - 1) < 0.25
    if errors == "independent":
        assert abs(near["corr_x"] - near["null"]) < 0.05 and abs(near["corr_y"] - near["null"]) < 0.05
    else:  # w exp(-d / L) at d = 10-20 mm, L = 30 mm: ~0.4-0.5, less the mean's share
        assert near["corr_x"] > 0.3 and near["corr_y"] > 0.3


def test_a_straight_drift_is_recovered():
    tracks, T, cam = _campaign(np.random.default_rng(6), _drift, n_tracks=100)
    _, drift = tool.surface_pairs(tracks, T, cam, cam.project, _Plane(), "p11")
    # every track drifts by 20 / -10 sigma per m (sigma 0.08 px): slopes 1.6 / 0.8 px per m, whose spread about zero
    # (1.4826 x the median absolute slope) is 1.4826 x that, seen in the reference view (~5 % smaller)
    assert drift["explained_median"] > 0.95
    assert np.allclose(drift["slope_x_px_per_m_robust_std"], 1.4826 * np.array([1.6, 0.8]), rtol=0.1)
