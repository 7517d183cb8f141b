"""MuJoCo's camera conventions, pinned in one place.

MuJoCo renders a pinhole camera whose frame looks along its −z axis with y up; the bench (and OpenCV) use an optical
frame with x right, y down, z forward and pixel (0, 0) at the centre of the top-left pixel. With the intrinsics
given as ``resolution="W H" sensorsize="W H" focal="fx fy" principal="px py"`` (one length unit per pixel) MuJoCo
4 projects a point ``(x, y, z)`` of the OpenCV frame to

    u = W/2 − px + fx x/z − 1/2,     v = H/2 − py + fy y/z − 1/2

(measured: both principal offsets enter with a minus sign, and the image is sampled at pixel centres, hence the half
pixel), so ``px = W/2 − 1/2 − cx`` and ``py = H/2 − 1/2 − cy`` reproduce ``K``. Skew cannot be rendered; it must
be zero here (the lens stage, which resamples anyway, maps a skew-free render onto any target camera).
``tests/sim/test_render.py`` renders small markers and finds them within 0.1 px of this projection.
"""

from __future__ import annotations

import numpy as np

#: The OpenCV optical frame expressed in MuJoCo's camera frame (and back): x kept, y and z flipped.
R_MJCAM_CV = np.diag([1.0, -1.0, -1.0])


def mujoco_camera_xml(name: str, K, width: int, height: int, T_parent_cam) -> str:
    """A ``<camera>`` element reproducing the OpenCV camera ``K`` (no skew) at ``T_parent_cam`` (OpenCV frame).

    Parameters
    ----------
    name : str
    K : array_like (3, 3)
        Intrinsics (px) with ``K[0, 1] == 0``.
    width, height : int
        Image size (px).
    T_parent_cam : array_like (4, 4)
        The optical frame (x right, y down, z forward) in the parent body's frame (m).
    """
    from bench.geometry.quaternion import matrix_to_quaternion

    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: expected a finite (3, 3) intrinsic matrix with fx, fy > 0, got {K.tolist()}")
    if abs(K[0, 1]) > 1e-12:
        raise ValueError(f"K: MuJoCo cannot render skew (K[0, 1] = {K[0, 1]}); render skew-free and resample")
    if int(width) <= 0 or int(height) <= 0:
        raise ValueError(f"image size: expected positive integers, got {width} x {height}")
    T = np.asarray(T_parent_cam, dtype=float)
    R_parent_mj = T[:3, :3] @ R_MJCAM_CV
    px = width / 2 - 0.5 - K[0, 2]
    py = height / 2 - 0.5 - K[1, 2]
    pos = " ".join(f"{v:.17g}" for v in T[:3, 3])
    quat = " ".join(f"{v:.17g}" for v in matrix_to_quaternion(R_parent_mj))
    return (f'<camera name="{name}" pos="{pos}" quat="{quat}" resolution="{int(width)} {int(height)}" '
            f'sensorsize="{int(width)} {int(height)}" focal="{K[0, 0]:.17g} {K[1, 1]:.17g}" '
            f'principal="{px:.17g} {py:.17g}"/>')


def camera_pose_cv(model, data, name: str) -> np.ndarray:
    """``T_world_cam`` (OpenCV optical frame) of MuJoCo camera ``name`` after ``mj_forward``."""
    import mujoco

    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cid < 0:
        raise ValueError(f"camera {name!r}: not in the model")
    T = np.eye(4)
    T[:3, :3] = data.cam_xmat[cid].reshape(3, 3) @ R_MJCAM_CV
    T[:3, 3] = data.cam_xpos[cid]
    return T
