import numpy as np
import pytest

from bench.sim.encoders import EncoderModel


def test_noise_quantisation_backlash():
    rng = np.random.default_rng(91)
    q = np.full((20000, 6), 0.3)
    noisy = EncoderModel(noise_std_rad=1e-4).read(q, rng)
    assert np.std(noisy - q) == pytest.approx(1e-4, rel=0.03) and abs(np.mean(noisy - q)) < 3e-6
    res = 1e-3
    quant = EncoderModel(resolution_rad=res).read(rng.uniform(-1, 1, (5000, 6)), rng)
    assert np.allclose(quant / res, np.round(quant / res), atol=1e-9)
    qq = rng.uniform(-1, 1, (5000, 6))  # quantisation error uniform in +-res/2: std res / sqrt(12)
    assert np.std(EncoderModel(resolution_rad=res).read(qq, rng) - qq) == pytest.approx(res / np.sqrt(12), rel=0.05)
    bl = EncoderModel(backlash_rad=2e-3)
    up, down = bl.read(np.zeros(6), rng, direction=np.ones(6)), bl.read(np.zeros(6), rng, direction=-np.ones(6))
    assert np.allclose(down - up, 2e-3) and np.allclose(bl.read(np.zeros(6), rng), 0.0)  # hysteresis = backlash
    off = EncoderModel(offset_rad=(1e-3, 0, 0, 0, 0, -1e-3)).read(np.zeros(6), rng)
    assert np.allclose(off, [1e-3, 0, 0, 0, 0, -1e-3])


def test_bad_parameters():
    with pytest.raises(ValueError, match="noise_std_rad"):
        EncoderModel(noise_std_rad=-1.0)
    with pytest.raises(ValueError, match="degrees"):
        EncoderModel(resolution_rad=0.5)
    with pytest.raises(ValueError, match="NaN"):
        EncoderModel().read(np.array([np.nan] * 6), np.random.default_rng(0))
