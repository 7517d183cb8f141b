"""Guided matching (bench.vision.guided): search by projection, one-to-one, ratio test within the window."""

import numpy as np
import pytest

from bench.vision.guided import search_by_projection


def _scene(rng, m=60, d=128):
    uv = rng.uniform(50, 590, (m, 2))
    desc = rng.normal(0, 1, (m, d)).astype(np.float32)
    return uv, desc


def test_finds_every_point_at_its_projection_and_nothing_else():
    rng = np.random.default_rng(1)
    uv, desc = _scene(rng)
    perm = rng.permutation(len(uv))
    uv_view = uv[perm] + rng.normal(0, 0.5, uv.shape)  # detected within a pixel, in another order
    desc_view = desc[perm] + rng.normal(0, 0.05, desc.shape).astype(np.float32)
    far = np.r_[uv_view, rng.uniform(50, 590, (200, 2))]  # plus unrelated keypoints
    far_desc = np.r_[desc_view, rng.normal(0, 1, (200, desc.shape[1])).astype(np.float32)]
    i_map, i_view = search_by_projection(uv, far, desc, far_desc, radius_px=3.0)
    inv = np.argsort(perm)
    assert np.array_equal(i_map, np.arange(len(uv)))
    assert np.array_equal(i_view, inv)


def test_outside_the_radius_is_not_a_candidate():
    uv = np.array([[100.0, 100.0]])
    desc = np.ones((1, 4), np.float32)
    i_map, _ = search_by_projection(uv, uv + [3.01, 0.0], desc, desc, radius_px=3.0)
    assert len(i_map) == 0
    i_map, _ = search_by_projection(uv, uv + [2.99, 0.0], desc, desc, radius_px=3.0)
    assert len(i_map) == 1


def test_ratio_test_within_the_window():
    uv = np.array([[100.0, 100.0]])
    d0 = np.zeros((1, 4), np.float32)
    kp = np.array([[101.0, 100.0], [99.0, 100.0]])
    close = np.array([[1.0, 0, 0, 0], [1.1, 0, 0, 0]], np.float32)  # second candidate as near: ambiguous
    assert len(search_by_projection(uv, kp, d0, close, radius_px=3.0, ratio=0.8)[0]) == 0
    clear = np.array([[1.0, 0, 0, 0], [3.0, 0, 0, 0]], np.float32)
    i_map, i_view = search_by_projection(uv, kp, d0, clear, radius_px=3.0, ratio=0.8)
    assert i_map.tolist() == [0] and i_view.tolist() == [0]
    alone = search_by_projection(uv, kp[:1], d0, close[1:], radius_px=3.0)  # a lone candidate: nothing to compare
    assert alone[0].tolist() == [0]


def test_one_map_point_per_keypoint_the_nearest_descriptor_keeps_it():
    uv = np.array([[100.0, 100.0], [102.0, 100.0]])
    desc = np.array([[0.0, 0, 0, 0], [5.0, 0, 0, 0]], np.float32)
    kp = np.array([[101.0, 100.0]])
    kd = np.array([[4.0, 0, 0, 0]], np.float32)  # nearer to map point 1's descriptor
    i_map, i_view = search_by_projection(uv, kp, desc, kd, radius_px=3.0)
    assert i_map.tolist() == [1] and i_view.tolist() == [0]


def test_nan_projections_empty_inputs_and_bad_arguments():
    uv = np.array([[np.nan, np.nan], [10.0, 10.0]])
    desc = np.eye(2, 4, dtype=np.float32)
    i_map, _ = search_by_projection(uv, np.array([[10.0, 10.0]]), desc, desc[1:], radius_px=1.0)
    assert i_map.tolist() == [1]
    assert len(search_by_projection(np.empty((0, 2)), uv[1:], desc[:0], desc, radius_px=1.0)[0]) == 0
    assert len(search_by_projection(uv, np.empty((0, 2)), desc, desc[:0], radius_px=1.0)[0]) == 0
    with pytest.raises(ValueError, match="radius_px"):
        search_by_projection(uv, uv, desc, desc, radius_px=0.0)
    with pytest.raises(ValueError, match="ratio"):
        search_by_projection(uv, uv, desc, desc, radius_px=1.0, ratio=1.5)

