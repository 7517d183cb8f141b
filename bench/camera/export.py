"""The calibrated camera for other tools: OpenCV FileStorage YAML and ROS ``camera_info`` YAML.

* ``opencv`` - the bench's own ``camera.yaml`` (:func:`bench.camera.io.camera_yaml_text`, written by
  ``cv2.FileStorage``): ``camera_matrix``, ``dist_coeffs`` (``k1, k2, p1, p2, k3``), ``image_width``,
  ``image_height``, plus the thesis's derived blocks. ``cv2.FileStorage(path, READ).getNode("camera_matrix").mat()``
  gives ``K``.
* ``ros`` - the ``camera_info`` file of ``camera_calibration_parsers`` (ROS 1 and 2): ``image_width``,
  ``image_height``, ``camera_name``, ``camera_matrix`` / ``distortion_coefficients`` / ``rectification_matrix`` /
  ``projection_matrix`` as ``{rows, cols, data}`` (row-major), ``distortion_model: plumb_bob`` (OpenCV's five
  coefficients, the bench's order). A monocular camera has ``R = I`` and ``P = [K | 0]`` (the rectified image keeps
  the calibrated focal lengths and principal point; ``image_proc`` then only removes the distortion).

Both conventions put pixel (0, 0) at the centre of the top-left pixel, as the bench does. Neither OpenCV's functions
nor ROS model skew (``K[0, 1]``): a camera whose skew moves a pixel by more than :data:`SKEW_TOLERANCE_PX` is refused
(one-line error) rather than exported to tools that would silently drop it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from bench.camera.io import camera_yaml_text, read_camera_yaml
from bench.camera.model import CameraModel
from bench.errors import ConfigError
from bench.fileio import check_output_file, write_output_file

FORMATS = ("opencv", "ros")
#: largest pixel shift the skew may cause over the image for an export to OpenCV/ROS (the parity target, px)
SKEW_TOLERANCE_PX = 1e-6


def skew_shift_px(camera: CameraModel) -> float:
    """Largest pixel shift over the image that dropping the skew ``K[0, 1]`` would cause (px).

    ``u = fx x + s y + cx`` (Eq. 50): ignoring ``s`` moves ``u`` by ``|s y|``, largest at the top or bottom row,
    where the distorted normalised coordinate is ``y = (v - cy) / fy``.
    """
    v_far = max(abs(-0.5 - camera.cy), abs(camera.height - 0.5 - camera.cy))
    return abs(camera.skew) * v_far / camera.fy


def check_exportable(camera: CameraModel, source: str = "<camera>") -> None:
    """One-line :class:`ConfigError` unless OpenCV and ROS can hold ``camera`` exactly (no significant skew)."""
    shift = skew_shift_px(camera)
    if shift > SKEW_TOLERANCE_PX:
        raise ConfigError(source, "camera_matrix[0][1]", f"skew {camera.skew:.6g} px moves pixels by up to "
                          f"{shift:.3g} px, and OpenCV/ROS have no skew; calibrate without skew to export")


def opencv_yaml_text(camera: CameraModel, source: str = "<camera>") -> str:
    """OpenCV FileStorage YAML of ``camera`` (the bench's ``camera.yaml``), after :func:`check_exportable`."""
    check_exportable(camera, source)
    return camera_yaml_text(camera)


def camera_info_text(camera: CameraModel, source: str = "<camera>") -> str:
    """ROS ``camera_info`` YAML (``camera_calibration_parsers`` format, ``plumb_bob``) of ``camera``.

    Parameters
    ----------
    camera : CameraModel
        Skew-free (see :func:`check_exportable`); ``dist`` is ``(k1, k2, p1, p2, k3)``.
    source : str
        Named in the error if the camera cannot be exported.

    Returns
    -------
    str
        Full double precision (``repr``), row-major matrices.
    """
    check_exportable(camera, source)
    K = np.array(camera.K, dtype=float)
    K[0, 1] = 0.0
    P = np.hstack([K, np.zeros((3, 1))])

    def matrix(M):
        M = np.atleast_2d(M)
        return {"rows": int(M.shape[0]), "cols": int(M.shape[1]), "data": [float(v) for v in M.ravel()]}

    info = {"image_width": int(camera.width), "image_height": int(camera.height), "camera_name": str(camera.name),
            "camera_matrix": matrix(K), "distortion_model": "plumb_bob",
            "distortion_coefficients": matrix(np.asarray(camera.dist, dtype=float).reshape(1, 5)),
            "rectification_matrix": matrix(np.eye(3)), "projection_matrix": matrix(P)}
    return yaml.safe_dump(info, sort_keys=False, default_flow_style=None, width=10_000)


def export_camera(camera_file, fmt: str, out, force: bool = False) -> Path:
    """Read ``camera.yaml`` and write it as ``fmt`` (``opencv`` or ``ros``) to ``out`` atomically; returns the path.

    ``force`` replaces an earlier output of ``bench export-camera`` edited since (never another file: see
    :func:`bench.fileio.check_output_file`)."""
    check_output_file(out, "export-camera", force=force)
    if fmt not in FORMATS:
        raise ConfigError("--format", fmt, f"expected one of {', '.join(FORMATS)}")
    camera = read_camera_yaml(camera_file)
    text = (opencv_yaml_text if fmt == "opencv" else camera_info_text)(camera, str(camera_file))
    return write_output_file(out, text, "export-camera", force=force)
