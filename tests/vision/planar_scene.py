"""A fast, geometrically exact in-situ dataset for tests: a textured planar panel imaged through homographies.

No MuJoCo: each view is ``cv2.warpPerspective`` of a random texture by the homography ``K R^T [s e_x, s e_y, O - t]``
of the panel plane, so SIFT finds real keypoints whose 3D positions are known exactly. The arm (nominal TA-40 model,
camera mount ``T_LINK5_CAM``) takes a reference view, five surrounding views (the survey), then the base moves by
``base_motion`` and two locate views ``locate_baseline`` apart are taken. Written with
:class:`bench.dataset.DatasetWriter` (``kind: in_situ``), readable by ``bench locate``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

from bench.camera.io import camera_yaml_text
from bench.camera.model import CameraModel
from bench.dataset import DatasetWriter
from bench.geometry.transforms import homogeneous, invert, transform_points
from bench.robot.calibration_file import write_calibrated_robot
from bench.robot.model import default_robot_path
from bench.sim.views import camera_frames, look_at_configuration, surrounding_eyes

T_LINK5_CAM = homogeneous(np.eye(3), [0.1, 0.0, 0.2])
Q_REF = np.deg2rad([30, 40, 60, 10, 80, 0])
SIZE = (640, 480)
FOCAL_PX = 800.0
K = np.array([[FOCAL_PX, 0.0, 319.5], [0.0, FOCAL_PX, 239.5], [0.0, 0.0, 1.0]])
PANEL_M = (1.0, 0.8)  # panel size (m), 2 mm per texture pixel
TEXEL_M = 0.002


def texture(rng: np.random.Generator) -> np.ndarray:
    """A grey texture rich in SIFT keypoints: blurred noise at three scales plus random discs."""
    h, w = int(PANEL_M[1] / TEXEL_M), int(PANEL_M[0] / TEXEL_M)
    img = np.zeros((h, w), np.float32)
    for sigma, weight in ((2.0, 0.5), (5.0, 1.0), (12.0, 1.5)):
        img += weight * cv2.GaussianBlur(rng.normal(size=(h, w)).astype(np.float32), (0, 0), sigma) * sigma
    for _ in range(300):
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        cv2.circle(img, c, int(rng.integers(3, 12)), float(rng.normal(0, 3)), -1)
    img = (img - img.min()) / np.ptp(img)
    return (255 * img).astype(np.uint8)


def render(tex: np.ndarray, T_world_cam: np.ndarray, origin: np.ndarray, ex: np.ndarray, ey: np.ndarray):
    """The panel (texture pixel ``(u, v)`` at ``origin + TEXEL_M (u ex + v ey)``, world frame) seen by a camera."""
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    H = K @ R.T @ np.column_stack([TEXEL_M * ex, TEXEL_M * ey, origin - t])
    return cv2.warpPerspective(tex, H / H[2, 2], SIZE, flags=cv2.INTER_LINEAR, borderValue=0)


def write_planar_dataset(root, robot, base_motion, seed: int = 0, locate_baseline: float = 0.15,
                         same_locate_view: bool = False) -> dict:
    """Write the dataset to ``root``; returns the truth ``{"T_world_base": (4, 4), "panel_points": ...}``.

    ``base_motion`` is ``T_base1_base2`` (the re-parking); the site (world) frame is the survey base frame.
    ``same_locate_view``: both locate views identical (zero baseline).
    """
    rng = np.random.default_rng(seed)
    tex = texture(rng)
    T_ref = camera_frames(robot, Q_REF, T_LINK5_CAM)
    target = T_ref[:3, 3] + 1.1 * T_ref[:3, 2]
    ex, ey = T_ref[:3, 0], T_ref[:3, 1]
    origin = target - 0.5 * PANEL_M[0] * ex - 0.5 * PANEL_M[1] * ey
    views = [("ref", "reference", Q_REF, T_ref)]
    offsets = [[0.16, 0], [-0.16, 0], [0, 0.16], [0, -0.16], [0.12, 0.12]]  # Eq. 199: 151 mm for d_n at f = 800
    for k, eye in enumerate(surrounding_eyes(T_ref, offsets)):
        sol = look_at_configuration(robot, eye, target, T_LINK5_CAM, q_seed=Q_REF)
        assert sol.success, sol.message
        views.append((f"s{k}", "surround", sol.q, camera_frames(robot, sol.q, T_LINK5_CAM)))
    T_world_base2 = np.asarray(base_motion, dtype=float)
    target_b2 = transform_points(invert(T_world_base2), target)
    for k, off in enumerate([[0.0, 0.0], [0.0 if same_locate_view else locate_baseline, 0.0]]):
        eye = surrounding_eyes(T_ref, [off])[0]
        sol = look_at_configuration(robot, eye, target_b2, T_LINK5_CAM, q_seed=Q_REF)
        assert sol.success, sol.message
        views.append((f"loc{k}", "locate", sol.q, T_world_base2 @ camera_frames(robot, sol.q, T_LINK5_CAM)))
    with DatasetWriter(root, kind="in_situ", name=Path(root).name, overwrite=True) as w:
        for name, role, q, T_world_cam in views:
            w.add_view(name, render(tex, T_world_cam, origin, ex, ey), q=q, role=role)
        w.write_text("camera.yaml", camera_yaml_text(CameraModel(SIZE[0], SIZE[1], K, name="planar")))
        write_calibrated_robot(w.path("robot.yaml"), default_robot_path(), robot, T_link5_cam=T_LINK5_CAM)
        w.write_text("truth/truth.yaml", yaml.safe_dump({"T_world_base_locate": T_world_base2.tolist()}))
    return {"T_world_base": T_world_base2}
