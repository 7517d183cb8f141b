import cv2
import numpy as np
import pytest

from bench.vision.features import (
    detect_sift,
    match_descriptors,
    orientation_difference,
    orientation_filter,
    prevailing_orientation_change,
)


def _texture(rng, h=480, w=640):
    """A seeded synthetic scene: blobs, lines and text on noise - plenty of SIFT structure. The twelve tags share no
    glyph (tags like "V-00" ... "V-11" repeat "V-0" and "V-1" at several places: with OpenCV 5.1's SIFT, 7 % of the
    unrotated view's matches went to a twin 200-380 px away, a property of the scene rather than of the matching)."""
    img = cv2.GaussianBlur(rng.integers(0, 256, (h // 8, w // 8), dtype=np.uint8), (0, 0), 1.0)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_CUBIC)
    for _ in range(60):
        c = tuple(int(v) for v in rng.integers(0, [w, h]))
        cv2.circle(img, c, int(rng.integers(4, 25)), int(rng.integers(0, 256)), -1)
    for k in range(12):
        tag = "ABCDEFGHJKLMNPRSTUWXYZ2345"[2 * k:2 * k + 2]
        cv2.putText(img, tag, tuple(int(v) for v in rng.integers(20, [w - 80, h - 10])),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.8, int(rng.integers(0, 256)), 2)
    return img


def test_orientation_difference_wraps_as_eq_106():
    assert orientation_difference(170.0, -170.0) == pytest.approx(-20.0)
    assert orientation_difference(-170.0, 170.0) == pytest.approx(20.0)
    assert orientation_difference(10.0, 30.0) == pytest.approx(-20.0)
    d = orientation_difference(np.array([179.0, -179.0, 0.0]), np.array([-179.0, 179.0, 0.0]))
    assert np.allclose(d, [-2.0, 2.0, 0.0])
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-180, 180, 1000), rng.uniform(-180, 180, 1000)
    d = orientation_difference(a, b)
    assert np.all((d > -180) & (d <= 180)) and np.allclose(np.mod(d - (a - b), 360.0) % 360.0, 0.0, atol=1e-9)


@pytest.mark.parametrize("angle_deg", [0.0, 35.0, -120.0, 178.0])
def test_rotated_view_matches_and_orientation_peak(angle_deg):
    rng = np.random.default_rng(11)
    img1 = _texture(rng)
    h, w = img1.shape
    A = cv2.getRotationMatrix2D((w / 2 - 0.5, h / 2 - 0.5), angle_deg, 0.9)  # CCW on screen by angle_deg
    img2 = cv2.warpAffine(img1, A, (w, h), flags=cv2.INTER_LINEAR, borderValue=128)
    f1, f2 = detect_sift(img1), detect_sift(img2)
    assert len(f1) > 150 and len(f2) > 100
    m = match_descriptors(f1, f2)
    kept, centre = orientation_filter(f1, f2, m)
    # keypoint orientation is CCW on screen: a view turned CCW by `angle` turns every keypoint by +angle
    assert abs(orientation_difference(-centre, angle_deg)) < 2.0
    pred = f1.uv[kept.i1] @ A[:, :2].T + A[:, 2]
    err = np.linalg.norm(pred - f2.uv[kept.i2], axis=1)
    assert np.mean(err < 2.0) > 0.9 and len(kept) > 50  # repeated glyphs leave a few ambiguous
    # the filter removes matches whose orientation disagrees: inject wrong ones
    bad = type(m)(np.arange(50), np.roll(np.arange(50), 7), np.zeros(50), np.zeros(50))
    kept_bad, _ = orientation_filter(f1, f2, bad, expected_deg=-angle_deg)
    d = orientation_difference(f1.angle_deg[bad.i1] - f2.angle_deg[bad.i2], -angle_deg)
    assert len(kept_bad) == int(np.sum(np.abs(d) <= 20.0)) < 50


def test_lowe_threshold_mapping_changes_the_count():
    rng = np.random.default_rng(5)
    img = _texture(rng)
    n_lowe = len(detect_sift(img))  # Lowe's 0.03 = OpenCV 0.09 with 3 layers
    raw = cv2.SIFT_create(contrastThreshold=0.09, edgeThreshold=10, enable_precise_upscale=True).detect(img, None)
    assert n_lowe == len(raw)
    assert len(detect_sift(img, contrast_threshold=0.01)) > n_lowe


def test_prevailing_change_wraps_around_180():
    rng = np.random.default_rng(9)
    d = orientation_difference(179.0 + rng.normal(0, 2.0, 300), 0.0)
    assert abs(orientation_difference(prevailing_orientation_change(d), 179.0)) < 0.5


def test_degenerate_inputs():
    flat = np.full((100, 120), 90, np.uint8)
    f = detect_sift(flat)
    assert len(f) == 0 and f.descriptors.shape == (0, 128)
    assert len(match_descriptors(f, f)) == 0
    kept, centre = orientation_filter(f, f, match_descriptors(f, f))
    assert len(kept) == 0 and np.isnan(centre)
    with pytest.raises(ValueError, match="image: expected"):
        detect_sift(np.zeros((0, 0), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        detect_sift(np.zeros((10, 10), np.float32))
    with pytest.raises(ValueError, match="ratio"):
        match_descriptors(f, f, ratio=1.5)


def test_keypoints_are_not_biased_by_the_upscaled_octave():
    """Gaussian blobs at known sub-pixel centres: SIFT keypoints land on them (OpenCV's default upscaling would put
    every one 0.25 px right and below)."""
    rng = np.random.default_rng(31)
    yy, xx = np.mgrid[0:480, 0:640].astype(float)
    img = np.full((480, 640), 40.0)
    centres = []
    for gy in range(60, 440, 70):
        for gx in range(60, 600, 70):
            c = np.array([gx, gy]) + rng.uniform(-0.5, 0.5, 2)
            centres.append(c)
            img += 180 * np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / (2 * 4.0**2))
    f = detect_sift(np.clip(img, 0, 255).astype(np.uint8))
    C = np.array(centres)
    d = np.linalg.norm(f.uv[:, None] - C[None], axis=2)
    near = d.min(axis=1) < 1.5
    offset = f.uv[near] - C[d.argmin(axis=1)[near]]
    assert near.sum() > len(C) and np.abs(offset.mean(axis=0)).max() < 0.02
