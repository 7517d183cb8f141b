"""bench.scenario.recording: what is logged is what rerun's own reader gives back; failures leave no file."""

import numpy as np
import pytest

from bench.geometry.transforms import homogeneous, random_rotation
from bench.scenario.recording import GREEN, RED, Recording, load_entities


def _rgba(c):
    return (c[0] << 24) | (c[1] << 16) | (c[2] << 8) | 255


def test_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    T = homogeneous(random_rotation(rng), [0.1, -0.2, 0.3])
    K = np.array([[900.0, 0.0, 320.5], [0.0, 880.0, 240.25], [0.0, 0.0, 1.0]])
    with Recording(tmp_path / "r.rrd", "test", "test-1") as rec:
        rec.frame("world/base", T, static=True)
        rec.set_time("view", 3)
        rec.camera("world/cam", T, K, (640, 480), keypoints_uv=[[1.0, 2.0], [3.0, 4.0]])
        rec.points("world/p", rng.normal(size=(4, 3)), inliers=[True, False, True, True])
        for d in (20, 30):
            rec.set_time("d_mm", d)
            rec.scalar("plots/err_x_mm", d / 10)
    assert [p.name for p in tmp_path.iterdir()] == ["r.rrd"]  # no temporary file left
    e = load_entities(tmp_path / "r.rrd")
    R = np.array(e["/world/base"]["Transform3D:mat3x3"][0]).reshape(3, 3).T  # column-major in rerun
    assert np.allclose(R, T[:3, :3], atol=1e-6) and np.allclose(e["/world/base"]["Transform3D:translation"][0],
                                                                 T[:3, 3], atol=1e-7)
    assert np.allclose(np.array(e["/world/cam"]["Pinhole:image_from_camera"][0]).reshape(3, 3).T, K)
    assert e["/world/cam"]["Pinhole:resolution"][0] == [[640.0, 480.0]]
    assert list(np.array(e["/world/p"]["Points3D:colors"][0], np.uint32)) == [_rgba(GREEN), _rgba(RED)] + \
        [_rgba(GREEN)] * 2
    assert [v[0] for v in e["/plots/err_x_mm"]["Scalars:scalars"]] == [2.0, 3.0]
    assert e["/world/cam/image/keypoints"]["Points2D:positions"][0] == [[1.0, 2.0], [3.0, 4.0]]


def test_failed_run_leaves_no_recording(tmp_path):
    with pytest.raises(RuntimeError):
        with Recording(tmp_path / "r.rrd", "test", "test-2") as rec:
            rec.frame("world/base", np.eye(4))
            raise RuntimeError("pipeline crashed")
    assert list(tmp_path.iterdir()) == []
