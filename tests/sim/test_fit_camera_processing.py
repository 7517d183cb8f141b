"""tools/fit_camera_processing.py: its edge model against closed forms, and a fit that recovers known parameters."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.special import ndtr

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("fit_camera_processing", ROOT / "tools" / "fit_camera_processing.py")
fcp = importlib.util.module_from_spec(spec)
spec.loader.exec_module(fcp)

T = np.arange(-10.0, 10.01, 1.0)


def test_model_without_processing_is_the_pixel_integrated_edge():
    """Linear, no sharpening, a sharp optics: the profile is the pixel-integrated step between the black and the
    white level; a wider optics widens it by the Gaussian's spread."""
    p = fcp.model_profile(T, 1.0, 0.04, 0.05, 0.0, 1.0, tone=False)
    assert p[0] == pytest.approx(255 * 0.04, abs=0.6) and p[-1] == pytest.approx(255, abs=0.6)
    assert np.all(np.diff(p) >= 0) and p[T == 2][0] == pytest.approx(255, abs=0.6)
    wide = fcp.model_profile(T, 1.0, 0.04, 1.5, 0.0, 1.0, tone=False)
    # at 1.5 sigma beyond the edge the blurred step has risen to Phi(1.5) of the way (pixel integration aside)
    rise = (wide[T == 2][0] - wide[0]) / (wide[-1] - wide[0])
    assert rise == pytest.approx(ndtr(2 / np.hypot(1.5, 12 ** -0.5)), abs=0.03)


def test_sharpening_dips_below_the_black_level_and_the_fit_recovers_it():
    truth = (1.15, 0.02, 0.6, 2.0, 1.6)  # k, rho, sigma_o, amount, sigma_u
    target = fcp.model_profile(T, *truth)
    assert target.min() < target[0] - 20  # the halo
    plain = fcp.model_profile(T, truth[0], truth[1], truth[2], 0.0, 1.0)
    assert plain.min() == pytest.approx(plain[0], abs=0.6)  # no halo without sharpening

    def cost(q):
        if not (0.3 < q[0] < 20 and 0 < q[1] < 0.2 and 0 <= q[2] < 5 and 0.3 < q[3] < 5):
            return 1e12
        return np.sum((fcp.model_profile(T, q[0], q[1], truth[2], q[2], q[3]) - target) ** 2)

    r = fcp._best(cost, ([1.3, 0.02, 2.0, 1.5], [2.0, 0.01, 1.0, 2.0], [1.5, 0.02, 3.0, 1.0]))
    assert np.sqrt(r.fun / len(T)) < 1.0
    assert r.x[0] == pytest.approx(truth[0], rel=0.1) and r.x[2] == pytest.approx(truth[3], rel=0.15)
    assert r.x[3] == pytest.approx(truth[4], rel=0.15)


def test_fit_prints_the_chain_parameters_of_the_camera(monkeypatch, capsys, tmp_path):
    """``fit`` turns the profile fit into the chain's own parameters: the exposure over the renders' white, the
    printed black from the renders' black ratio (the ideal scene's 0.03), the sharpening as fitted; ``main`` prints
    them as ``--set camera.imaging_params...`` overrides."""
    chain = (0.98, 0.036, 0.6)  # the linear renders: white level, black ratio, optics sigma
    truth = (1.15, 0.02, 2.0, 1.6)  # the camera: k, rho, amount, sigma_u
    profiles = {"real": fcp.model_profile(T, truth[0], truth[1], chain[2], truth[2], truth[3]),
                "chain": fcp.model_profile(T, chain[0], chain[1], chain[2], 0.0, 1.0, tone=False)}
    monkeypatch.setattr(fcp, "profile_of", lambda folder, pattern: (T, profiles[Path(folder).name], 100))
    out = fcp.fit("real", "chain", (7, 7))
    p = out["imaging_params"]
    assert out["chain_white"] == pytest.approx(chain[0], rel=0.02)
    assert p["tone.exposure_scale"] == pytest.approx(truth[0] / chain[0], rel=0.1)
    assert p["toner.black_reflectance"] == pytest.approx(fcp.BLACK_REFLECTANCE * truth[1] / chain[1], rel=0.15)
    assert p["sharpen.amount"] == pytest.approx(truth[2], rel=0.15)
    assert p["sharpen.sigma_px"] == pytest.approx(truth[3], rel=0.15)
    for name in ("real", "chain"):
        (tmp_path / name).mkdir()
    assert fcp.main(["--data", str(tmp_path / "real"), "--chain", str(tmp_path / "chain")]) == 0
    printed = capsys.readouterr().out
    assert "--set camera.imaging_params.sharpen.sigma_px=" in printed
    assert "--set camera.imaging_params.toner.black_reflectance=" in printed


def test_fit_refuses_a_chain_that_is_already_sharpened(monkeypatch):
    """Renders made with the processing on (a user who forgot ``camera.imaging_off``) are a one-line error, not a fit
    of the processing on top of itself."""
    sharpened = fcp.model_profile(T, 1.15, 0.02, 0.6, 2.0, 1.6)
    monkeypatch.setattr(fcp, "profile_of", lambda folder, pattern: (T, sharpened, 100))
    with pytest.raises(SystemExit, match=r"--chain chain: the renders' edge dips \d+ DN below their black level"):
        fcp.fit("real", "chain", (7, 7))
