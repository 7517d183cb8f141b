"""Keypoints aligned by their image patches (bench.vision.patch_align): on a texture seen through a known affine map
the aligned keypoints land on the true correspondences far closer than their start; the local affine maps are exact
on exact matches and ignore a wrong neighbour; wrong matches and patches off the image keep their start."""

import cv2
import numpy as np
import pytest

from bench.vision.patch_align import MAX_SHIFT_PX, align, align_view, grey, local_affines

H, W = 240, 320
SCALE = 4  # the textures are drawn at 4x and area-averaged, as a sensor integrates


def _scene(rng, A, noise=1.0):
    """A smooth random texture (reference image) and the same texture through the affine map ``A`` (2, 3) of the
    image plane (view), both with sensor noise; ``to_view(u)`` maps reference pixels to view pixels exactly."""
    big = cv2.GaussianBlur(rng.random((H * SCALE, W * SCALE)).astype(np.float32), (0, 0), 6) * 765
    S = np.diag([SCALE, SCALE, 1.0])
    c = (SCALE - 1) / 2  # pixel centres: pixel u of the small image is big pixel SCALE u + c
    Sh = np.array([[1, 0, c], [0, 1, c], [0, 0, 1.0]])
    M = Sh @ S @ np.vstack([A, [0, 0, 1]]) @ np.linalg.inv(Sh @ S)
    view_big = cv2.warpAffine(big, M[:2], (W * SCALE, H * SCALE), flags=cv2.INTER_CUBIC)

    def small(img):
        return cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA) + rng.normal(0, noise, (H, W)).astype(np.float32)

    return small(big), small(view_big), lambda u: u @ A[:, :2].T + A[:, 2]


A_VIEW = np.array([[0.88, 0.10, 12.0], [-0.06, 1.04, -6.0]])  # foreshortening, shear and a shift


def test_aligned_keypoints_land_on_the_true_correspondences():
    rng = np.random.default_rng(1)
    ref, view, to_view = _scene(rng, A_VIEW)
    u = rng.uniform(30, [W - 45, H - 30], (150, 2))
    true = to_view(u)
    start = true + rng.normal(0, 0.3, true.shape)  # a detector's error
    uv, al = align_view(ref, view, u, start, np.arange(len(u)), np.arange(len(u)))
    assert al.ok.mean() > 0.95
    err = np.linalg.norm(uv[al.ok] - true[al.ok], axis=1)
    err0 = np.linalg.norm(start[al.ok] - true[al.ok], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.06 < 0.3 < np.sqrt(np.mean(err0 ** 2))
    assert np.all(np.abs(np.mean(uv[al.ok] - true[al.ok], axis=0)) < 0.01)  # no common shift
    assert np.allclose(al.uv[al.ok], uv[al.ok]) and np.all(al.ncc[al.ok] > 0.95)


def test_alignment_needs_no_detector_error_to_start_from():
    """Started on the true correspondences (noise-free images, the true affine map), the alignment stays there
    to the interpolation's precision."""
    rng = np.random.default_rng(2)
    ref, view, to_view = _scene(rng, A_VIEW, noise=0.0)
    u = rng.uniform(30, [W - 45, H - 30], (80, 2))
    al = align(ref, view, u, to_view(u), np.tile(A_VIEW[:, :2], (len(u), 1, 1)))
    assert al.ok.all()
    assert np.sqrt(np.mean(np.sum((al.uv - to_view(u)) ** 2, axis=1))) < 0.05


def test_local_affines_are_exact_on_exact_matches_and_ignore_a_wrong_neighbour():
    rng = np.random.default_rng(3)
    u = rng.uniform(0, [W, H], (60, 2))
    v = u @ A_VIEW[:, :2].T + A_VIEW[:, 2]
    A, ok = local_affines(u, v)
    assert ok.all() and np.max(np.abs(A - A_VIEW[:, :2])) < 1e-9
    v_bad = v.copy()
    v_bad[7] += [40.0, -25.0]  # a wrong match: a neighbour of several others
    A, ok = local_affines(u, v_bad)
    others = np.arange(60) != 7
    assert ok[others].all() and np.max(np.abs(A[others] - A_VIEW[:, :2])) < 1e-9
    assert not local_affines(u[:3], v[:3])[1].any()  # three matches: no affine map
    line = np.c_[np.linspace(0, 100, 10), np.full(10, 5.0)]
    assert not local_affines(line, line)[1].any()  # collinear neighbours


def test_wrong_matches_and_patches_off_the_image_keep_their_start():
    rng = np.random.default_rng(4)
    ref, view, to_view = _scene(rng, A_VIEW)
    u = np.array([[100.0, 100.0], [150.0, 120.0], [3.0, 100.0]])  # the last one's patch leaves the reference
    start = to_view(u)
    start[0] = [250.0, 60.0]  # a wrong match: another place of the texture
    al = align(ref, view, u, start, np.tile(A_VIEW[:, :2], (3, 1, 1)))
    assert not al.ok[0] and al.ok[1] and not al.ok[2]
    assert np.array_equal(al.uv[[0, 2]], start[[0, 2]])
    assert np.all(al.shift_px[al.ok] <= MAX_SHIFT_PX)


def test_align_view_moves_only_the_matched_keypoints_and_keeps_the_better_of_two_matches():
    rng = np.random.default_rng(5)
    ref, view, to_view = _scene(rng, A_VIEW)
    u = rng.uniform(30, [W - 45, H - 30], (40, 2))
    v = np.r_[to_view(u) + rng.normal(0, 0.3, (40, 2)), [[10.0, 10.0]]]  # one view keypoint is matched to nothing
    v_in = v.copy()
    i_ref = np.r_[np.arange(40), 0]
    i_view = np.r_[np.arange(40), 5]  # view keypoint 5 matched twice: to reference 5 and (worse) to reference 0
    dist = np.r_[np.full(40, 0.1), 0.9]
    uv, al = align_view(ref, view, u, v, i_ref, i_view, dist)
    assert np.array_equal(v, v_in)  # the input is not changed
    assert len(al.ok) == 40 and np.array_equal(uv[40], v[40])
    assert np.linalg.norm(uv[5] - to_view(u[5:6])[0]) < 0.1  # aligned on its own reference keypoint, not on 0's


def test_grey_is_the_detectors_grey():
    rgb = np.random.default_rng(6).integers(0, 256, (8, 9, 3), dtype=np.uint8)
    assert grey(rgb).dtype == np.float32
    assert np.array_equal(grey(rgb), cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32))
    assert np.array_equal(grey(rgb[..., 0]), rgb[..., 0].astype(np.float32))


@pytest.mark.parametrize("n", [0, 1])
def test_too_few_matches_give_no_alignment(n):
    rng = np.random.default_rng(7)
    ref, view, _ = _scene(rng, A_VIEW)
    u = rng.uniform(30, [W - 45, H - 30], (n, 2))
    uv, al = align_view(ref, view, u, u, np.arange(n), np.arange(n))
    assert not al.ok.any() and np.array_equal(uv, u)
