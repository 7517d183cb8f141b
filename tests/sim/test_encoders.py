import numpy as np
import pytest

from bench.sim.encoders import EncoderModel, motion_directions


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


def test_backlash_hysteresis_loop_along_a_sweep():
    """Sweep a joint up and back down: the readings trace a loop of width = backlash, offset by -/+ backlash / 2."""
    rng = np.random.default_rng(92)
    up = np.linspace(-0.2, 0.2, 41)
    sweep = np.concatenate([up, up[::-1][1:]])
    q = np.zeros((len(sweep), 6))
    q[:, 2] = sweep
    q[:, 4] = 0.1  # never moves
    direction = motion_directions(q)
    assert direction[0, 2] == 0 and np.all(direction[1:41, 2] == 1) and np.all(direction[41:, 2] == -1)
    assert np.all(direction[:, 4] == 0)
    enc = EncoderModel(noise_std_rad=2e-5, resolution_rad=1e-5, backlash_rad=1e-3)
    r = enc.read(q, rng, direction)
    err = r[:, 2] - q[:, 2]
    assert abs(err[1:41].mean() + 5e-4) < 1e-5 and abs(err[41:].mean() - 5e-4) < 1e-5  # mean of 40 noisy readings
    going_up, coming_down = r[1:40, 2], r[41:80, 2][::-1]  # the same true angles from either side
    assert abs(np.mean(coming_down - going_up) - 1e-3) < 1.5e-5  # loop width = backlash (noise 2e-5 / sqrt(39) * 2)
    assert np.abs(r[:, 4] - 0.1).max() < 1e-4  # no motion, no backlash offset
    pause = motion_directions(np.array([[0.0], [1.0], [1.0], [0.5], [0.5]]))
    assert pause.ravel().tolist() == [0, 1, 1, -1, -1]  # a pause keeps the last direction


def test_bad_parameters():
    with pytest.raises(ValueError, match="noise_std_rad"):
        EncoderModel(noise_std_rad=-1.0)
    with pytest.raises(ValueError, match="degrees"):
        EncoderModel(resolution_rad=0.5)
    with pytest.raises(ValueError, match="NaN"):
        EncoderModel().read(np.array([np.nan] * 6), np.random.default_rng(0))
    with pytest.raises(ValueError, match="q_sequence"):
        motion_directions(np.zeros(6))


def test_drive_to_is_the_inverse_of_read():
    """A servo commanded to read q settles where the encoder reads q: read(drive_to(q)) = q up to noise/quantum."""
    rng = np.random.default_rng(93)
    q_cmd = rng.uniform(-1, 1, (4000, 6))
    exact = EncoderModel(offset_rad=(1e-3, -2e-3, 0, 0, 5e-4, 0), backlash_rad=1e-3)
    d = np.where(rng.uniform(size=q_cmd.shape) < 0.5, 1.0, -1.0)
    q_true = exact.drive_to(q_cmd, rng, d)
    assert np.abs(exact.read(q_true, rng, d) - q_cmd).max() < 1e-15  # noise-free: exact inverse
    assert np.allclose(q_true - q_cmd, -np.array(exact.offset_rad) + d * 5e-4)
    res, sig = 1e-4, 2e-5
    enc = EncoderModel(noise_std_rad=sig, resolution_rad=res)
    err = enc.drive_to(q_cmd, rng) - q_cmd  # noise + uniform quantum: std sqrt(sig^2 + res^2 / 12)
    assert np.std(err) == pytest.approx(np.sqrt(sig**2 + res**2 / 12), rel=0.05) and abs(err.mean()) < 3e-6
    with pytest.raises(ValueError, match="q_command"):
        enc.drive_to([np.inf] * 6, rng)
