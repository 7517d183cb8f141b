"""The in-situ kind's lab step: the priors it writes for the joint bundle (bench.scenario.in_situ_lab)."""

from types import SimpleNamespace

import numpy as np

from bench.scenario.in_situ_lab import _lab_priors, lab_k3_prior
from bench.vision.joint_bundle import K3_PRIOR_SD, lab_prior


def _cal(rng, k3: bool):
    names = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"] + (["k3"] if k3 else []) + ["skew"]
    A = rng.normal(size=(len(names), len(names)))
    return SimpleNamespace(parameter_names=names, covariance=A @ A.T + 0.1 * np.eye(len(names)))


def _cfg(**pipeline):
    return {"pipeline": {"refine_distortion": True, "refine_k3": False, "lab_k3": False, "camera_model": "central",
                         **pipeline}}


def test_lab_priors_carry_the_labs_own_k3_with_its_cross_covariances():
    """A lab that fitted k3, with refine_k3: the lens block is the calibration's own 5 x 5 (k1 k2 p1 p2 k3) with its
    cross-covariances to the intrinsics, and the rig tolerances' (15, 15) is added; a lab that held k3 at zero: the
    4 x 4 block and the wide independent k3 sd; refine_k3 off: the 4 x 4 block alone (the lab's k3 held)."""
    rng = np.random.default_rng(3)
    he = SimpleNamespace(rms_rot_rad=1e-3, rms_trans_m=2e-4)
    cal5, cal4 = _cal(rng, True), _cal(rng, False)
    on = _cfg(refine_k3=True, lab_k3=True)
    assert lab_k3_prior(cal5, on["pipeline"]) and not lab_k3_prior(cal4, on["pipeline"])
    assert not lab_k3_prior(cal5, _cfg(lab_k3=True)["pipeline"])
    p = _lab_priors(cal5, he, 9, on)
    assert p["cov_dist"].shape == (5, 5) and "k3_sd" not in p
    assert np.array_equal(lab_prior(p["cov_K"], p["cov_dist"], None, p["cov_K_dist"])[:9, :9], cal5.covariance[:9, :9])
    B = rng.normal(size=(15, 15))
    tol = B @ B.T * 1e-6
    t = _lab_priors(cal5, he, 9, on, tol)
    assert t["cov_dist_mount"].shape == (5, 6) and np.allclose(t["cov_dist_mount"], tol[4:9, 9:])
    assert np.allclose(t["cov_mount"], tol[9:, 9:] + np.diag([1e-6] * 3 + [4e-8] * 3) / 9)
    q = _lab_priors(cal4, he, 9, on)
    assert q["cov_dist"].shape == (4, 4) and q["k3_sd"] == K3_PRIOR_SD
    off = _lab_priors(cal5, he, 9, _cfg(lab_k3=True))
    assert off["cov_dist"].shape == (4, 4) and "k3_sd" not in off
    assert np.array_equal(off["cov_dist"], cal5.covariance[4:8, 4:8])
