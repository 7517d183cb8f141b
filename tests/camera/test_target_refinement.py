"""Calibration on the two-plane rig with the printout's structure estimated (bench.camera.target_refinement)."""

import sys
from pathlib import Path

import numpy as np
import pytest

from bench.camera.target_refinement import calibrate_camera_refining_rig, rig_basis
from bench.sim.imaging import imaging_profile, target_geometry
from bench.sim.scenes.rig import calibration_rig

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_calibration import SIZE, TRUE_DIST, TRUE_K, random_views  # noqa: E402


def _printout(off=()):
    """The printout errors this module models (line offsets at the in-plane-only measurement's 0.28 mm, bow, fold,
    scale): the cockle is a random field, not in the basis (bench.camera.target_tolerance carries it as a
    covariance), so it is off here."""
    return imaging_profile("realistic", [*off, "cockle", "handling"],
                           overrides={"print_lines": {"feed_rms_mm": 0.28, "scan_rms_mm": 0.03}})


def test_rig_basis_spans_the_simulated_printout():
    """The simulator's print errors (line offsets, bow, fold; no scale) are in the basis's span: least squares
    recovers the true corners to the linearisation of the fold (< 1 um)."""
    nominal = calibration_rig().features["corners"]
    e = target_geometry(_printout(["print_scale"]), 7, np.random.default_rng(3))
    true = calibration_rig(errors=e).features["corners"]
    A, sig = rig_basis(nominal)
    assert A.shape == (216, 27) and sig.shape == (27,)
    theta = np.linalg.lstsq(A, (true - nominal).ravel(), rcond=None)[0]
    assert np.abs(A @ theta - (true - nominal).ravel()).max() < 1e-6
    assert np.abs(true - nominal).max() > 2e-4  # the errors are there to be found
    with pytest.raises(ValueError, match="two-plane rig"):
        rig_basis(np.c_[np.random.default_rng(0).random((10, 2)), np.zeros(10)] + [0.1, 0.1, 0])


def test_printout_errors_no_longer_bias_the_focal_length():
    """Six printed rigs (the simulator's realistic target errors), nine views each at 0.9 m, 0.05 px noise: the
    nominal calibration's focal error (0.002-0.4 %, measured) is the printout's; estimating the printout more than
    halves it on average, and the image residual drops to the noise."""
    nominal = calibration_rig().features["corners"]
    f_nominal, f_refined = [], []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        e = target_geometry(_printout(), 7, np.random.default_rng(np.random.SeedSequence([seed, 1])))
        true = calibration_rig(errors=e).features["corners"]
        _, uvs, _ = random_views(rng, TRUE_K, TRUE_DIST, true, 9, distance=0.9)
        uvs = [uv + rng.normal(0, 0.05, uv.shape) for uv in uvs]
        out = calibrate_camera_refining_rig([nominal] * 9, uvs, SIZE, "heikkila", sigma_px=0.05)
        assert out.calibration.success, out.calibration.message
        assert out.theta.shape == (27,) and out.offsets.shape == (72, 3)
        f_nominal.append(abs(out.nominal.K[0, 0] / TRUE_K[0, 0] - 1))
        f_refined.append(abs(out.calibration.K[0, 0] / TRUE_K[0, 0] - 1))
        assert out.calibration.rms_px < min(out.nominal.rms_px, 0.08)  # ~ the 0.05 px noise (x sqrt 2)
    assert np.mean(f_refined) < 0.6 * np.mean(f_nominal), (f_nominal, f_refined)
