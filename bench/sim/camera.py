"""MuJoCo's camera conventions, pinned in one place.

MuJoCo renders a pinhole camera whose frame looks along its −z axis with y up; the bench (and OpenCV) use an optical
frame with x right, y down, z forward and pixel (0, 0) at the centre of the top-left pixel. The two frames differ by
the fixed rotation :data:`R_MJCAM_CV` (x kept, y and z flipped). With the intrinsics given as
``resolution = (W, H)``, ``sensor_size = (W, H)``, ``focal_length = (fx, fy)``, ``principal_length = (px, py)``
(one length unit per pixel; MJCF ``resolution``, ``sensorsize``, ``focal``, ``principal``) MuJoCo 4 projects a
point ``(x, y, z)`` of the OpenCV frame to

    u = W/2 − px + fx x/z − 1/2,     v = H/2 − py + fy y/z − 1/2

(measured: both principal offsets enter with a minus sign, and the image is sampled at pixel centres, hence the half
pixel), so ``px = W/2 − 1/2 − cx`` and ``py = H/2 − 1/2 − cy`` reproduce ``K``; ``fx != fy`` (non-square pixels)
is rendered exactly (up to MuJoCo's float32 storage of the intrinsics, ~1e-6 px). The frustum is fixed by the
lengths, not by the pixel count: rendering the same camera into an ``s W x s H`` framebuffer gives the supersampled
pinhole ``K_s`` with ``f_s = s f`` and ``c_s = s (c + 1/2) − 1/2``, whose ``s x s`` box average is again the pinhole
``K`` (:class:`bench.sim.render.Renderer`).

Skew cannot be rendered: :func:`mujoco_camera_attributes` refuses ``K[0, 1] != 0``. The contract with the optics
stages is: *the render is a skew-free pinhole with ``K_render``; the lens stage maps it to the target camera* —
:func:`bench.sim.distortion.render_K` picks a skew-free ``K_render`` covering any target (skew, distortion) and
:class:`bench.sim.distortion.DistortionStage` resamples the render onto the target ``K`` exactly.

``tests/sim/test_camera_render.py`` renders fronto-parallel discs at known points through the link-5 camera of the
arm and finds their centroids within 0.1 px of this projection (raw and supersampled renders).
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import homogeneous

#: The OpenCV optical frame expressed in MuJoCo's camera frame (and back): x kept, y and z flipped.
R_MJCAM_CV = np.diag([1.0, -1.0, -1.0])


def mujoco_camera_attributes(K, width: int, height: int) -> dict:
    """``mujoco.MjsCamera`` intrinsic fields that render the OpenCV pinhole ``K`` at ``width x height`` px.

    Parameters
    ----------
    K : array_like (3, 3)
        Intrinsics (px), OpenCV convention (pixel (0, 0) = centre of the top-left pixel), ``K[0, 1] == 0``.
    width, height : int
        Image size (px).

    Returns
    -------
    dict
        ``{"resolution": [W, H], "sensor_size": [W, H], "focal_length": [fx, fy], "principal_length": [px, py]}``
        (sensor lengths in pixels), with ``px = W/2 − 1/2 − cx`` and ``py = H/2 − 1/2 − cy``.
    """
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K: expected a finite (3, 3) intrinsic matrix, got shape {K.shape}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K: focal lengths must be positive (fx, fy > 0), got fx = {K[0, 0]}, fy = {K[1, 1]}")
    if abs(K[0, 1]) > 1e-12:
        raise ValueError(f"K: MuJoCo cannot render skew (K[0, 1] = {K[0, 1]}); render skew-free and resample "
                         "(bench.sim.distortion.render_K)")
    if np.abs(K[2] - [0.0, 0.0, 1.0]).max() > 1e-12 or abs(K[1, 0]) > 1e-12:
        raise ValueError(f"K: expected an upper-triangular intrinsic matrix with last row (0, 0, 1), got {K.tolist()}")
    if isinstance(width, bool) or isinstance(height, bool) or int(width) != width or int(height) != height \
            or width <= 0 or height <= 0:
        raise ValueError(f"image size: expected positive integers, got {width} x {height}")
    w, h = int(width), int(height)
    return {"resolution": [w, h], "sensor_size": [float(w), float(h)], "focal_length": [K[0, 0], K[1, 1]],
            "principal_length": [w / 2 - 0.5 - K[0, 2], h / 2 - 0.5 - K[1, 2]]}


def add_opencv_camera(parent, name: str, K, width: int, height: int, T_parent_cam):
    """Add to the ``mujoco.MjsBody`` ``parent`` a camera reproducing the OpenCV camera ``K`` (no skew).

    Parameters
    ----------
    parent : mujoco.MjsBody
    name : str
    K : array_like (3, 3)
        Intrinsics (px) with ``K[0, 1] == 0``.
    width, height : int
        Image size (px).
    T_parent_cam : array_like (4, 4)
        The optical frame (x right, y down, z forward) in the parent body's frame (m).

    Returns
    -------
    mujoco.MjsCamera
    """
    from bench.geometry.quaternion import matrix_to_quaternion
    from bench.geometry.transforms import check_transform

    attrs = mujoco_camera_attributes(K, width, height)
    T = check_transform(T_parent_cam, "T_parent_cam")
    if T.shape != (4, 4):
        raise ValueError(f"T_parent_cam: expected one (4, 4) transform, got shape {T.shape}")
    return parent.add_camera(name=name, pos=T[:3, 3].copy(), quat=matrix_to_quaternion(T[:3, :3] @ R_MJCAM_CV),
                             **attrs)


def _camera_id(model, name: str) -> int:
    import mujoco

    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cid < 0:
        raise ValueError(f"camera {name!r}: not in the model")
    return cid


def opencv_intrinsics(model, name: str, width: int, height: int) -> np.ndarray:
    """The OpenCV ``K`` (3, 3) of what MuJoCo camera ``name`` renders into a ``width x height`` framebuffer.

    The inverse of :func:`mujoco_camera_attributes` for cameras given by ``focal``/``sensorsize``/``principal``
    (any length unit, any framebuffer size); for ``fovy`` cameras ``fx = fy = (H/2) / tan(fovy/2)`` and the
    principal point is the image centre.
    """
    cid = _camera_id(model, name)
    w, h = int(width), int(height)
    sensor = np.asarray(model.cam_sensorsize[cid], dtype=float)
    K = np.eye(3)
    if sensor[0] > 0 and sensor[1] > 0:
        fxl, fyl, pxl, pyl = np.asarray(model.cam_intrinsic[cid], dtype=float)
        sx, sy = w / sensor[0], h / sensor[1]  # px per sensor length unit
        K[0, 0], K[1, 1] = fxl * sx, fyl * sy
        K[0, 2], K[1, 2] = w / 2 - 0.5 - pxl * sx, h / 2 - 0.5 - pyl * sy
    else:
        f = (h / 2) / np.tan(np.deg2rad(model.cam_fovy[cid]) / 2)
        K[0, 0] = K[1, 1] = f
        K[0, 2], K[1, 2] = w / 2 - 0.5, h / 2 - 0.5
    return K


def camera_pose_cv(model, data, name: str) -> np.ndarray:
    """``T_world_cam`` (OpenCV optical frame) of MuJoCo camera ``name`` after ``mj_forward``/``mj_kinematics``."""
    cid = _camera_id(model, name)
    return homogeneous(data.cam_xmat[cid].reshape(3, 3) @ R_MJCAM_CV, data.cam_xpos[cid])
