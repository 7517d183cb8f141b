"""``camera.yaml``: a camera's intrinsics and distortion in an OpenCV FileStorage-compatible file.

Keys (``../shared/design.md``)::

    camera_matrix   3x3 !!opencv-matrix (px), Eq. 50 in OpenCV layout (skew in K[0, 1])
    dist_coeffs     1x5 !!opencv-matrix, (k1, k2, p1, p2, k3) on normalised coordinates
    image_width, image_height   px
    model           pinhole | radial | heikkila
    name            the camera's name
    pixel_pitch_mm  (optional) sensor pixel size, needed for the Heikkilä parameters
    intrinsics_eq50 the thesis's alpha_px, beta_px, theta_deg, u0_px, v0_px (Eq. 50), derived
    heikkila_eq75   (when the camera has a pixel pitch, no skew and no k3) the thesis's s_u, f_px, f_mm, u0_px,
                    v0_px, k1_per_mm2, k2_per_mm4, T1_per_mm, T2_per_mm, pixels_per_mm (Tables 9/15 form), derived
    extra           (optional) a flat mapping of numbers/strings the writer wants to keep (e.g. reprojection RMS)
    flat_port       (optional) a refractive camera (:class:`bench.camera.refractive.RefractiveCamera`): the matrices
                    are then the *lens's* (inside the housing, in air) and this block the port in the lens frame:
                    lens_to_glass_mm, glass_thickness_mm, n_air, n_glass, n_water, tilt_x_deg, tilt_y_deg,
                    working_range_m. Read only where a refractive camera is accepted (``allow_refractive``).

``camera_matrix`` and ``dist_coeffs`` are authoritative; the derived blocks are written for people and checked on
reading (a block that disagrees with the matrices is an error). ``cv2.FileStorage`` reads these files and the reader
accepts files written by OpenCV (also the calibration sample's ``distortion_coefficients`` and its bookkeeping keys,
which are ignored). Note that OpenCV's own functions ignore ``K[0, 1]`` (they have no skew). Errors are one-line
:class:`~bench.errors.ConfigError` naming the file and the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import cv2
import numpy as np
from pydantic import Field, PlainValidator, model_validator
from pydantic_core import PydanticCustomError

from bench.camera.dlt import thesis_parameters
from bench.camera.heikkila import heikkila_of
from bench.camera.model import CameraModel
from bench.camera.presets import Eq50, Heikkila75
from bench.config import KeyProblem, PositiveFloat, Section, at_least, at_most, parse
from bench.errors import ConfigError
from bench.fileio import atomic_write_text, read_yaml

#: keys that OpenCV's calibration sample writes beside the camera; accepted and ignored
_OPENCV_SAMPLE_KEYS = {"distortion_coefficients", "calibration_time", "nr_of_frames", "nrOfFrames", "board_width",
                       "board_height", "board_Width", "board_Height", "square_size", "square_Size", "flags",
                       "calibrate_FixAspectRatio", "fisheye_model", "avg_reprojection_error",
                       "per_view_reprojection_errors", "extrinsic_parameters", "image_points", "grid_points",
                       "aspectRatio", "fix_aspect_ratio", "image_size"}
#: relative tolerance between the derived blocks and the matrices on reading
_CONSISTENCY_RTOL = 1e-9


def thesis_blocks(camera: CameraModel) -> dict:
    """The derived blocks ``intrinsics_eq50`` and (when defined) ``heikkila_eq75`` of a camera, file units."""
    alpha, beta, theta, u0, v0 = thesis_parameters(camera.K)
    out = {"intrinsics_eq50": {"alpha_px": alpha, "beta_px": beta, "theta_deg": float(np.rad2deg(theta)),
                               "u0_px": u0, "v0_px": v0}}
    if camera.pixel_pitch is not None and camera.skew == 0 and camera.dist[4] == 0:
        h = heikkila_of(camera)
        mm = 1e-3
        out["heikkila_eq75"] = {"s_u": h.s_u, "f_px": h.f_px, "f_mm": h.f / mm, "u0_px": h.u0, "v0_px": h.v0,
                                "k1_per_mm2": h.k1 * mm**2, "k2_per_mm4": h.k2 * mm**4, "T1_per_mm": h.p1 * mm,
                                "T2_per_mm": h.p2 * mm, "pixels_per_mm": mm / h.pixel_pitch}
    return out


def camera_yaml_text(camera, extra: dict | None = None) -> str:
    """The text of ``camera.yaml`` for ``camera`` (a :class:`CameraModel` or a
    :class:`~bench.camera.refractive.RefractiveCamera`: its lens, then the ``flat_port`` block; written by
    ``cv2.FileStorage``)."""
    port = None
    if not isinstance(camera, CameraModel):  # a refractive camera: the lens's matrices and the port
        port = {"lens_to_glass_mm": camera.port.d0 * 1e3, "glass_thickness_mm": camera.port.t * 1e3,
                "n_air": camera.port.n_air, "n_glass": camera.port.n_glass, "n_water": camera.port.n_water,
                "tilt_x_deg": float(np.rad2deg(camera.port.tilt[0])),
                "tilt_y_deg": float(np.rad2deg(camera.port.tilt[1])), "working_range_m": camera.working_range_m}
        if camera.port.decentre.any():
            raise ValueError("flat_port: a decentred port is written with its decentre absorbed into d0 (use "
                             "port.centred(), or the port calibration's)")
        camera = camera.lens.replace(name=camera.name)
    fs = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("camera_matrix", np.asarray(camera.K, dtype=np.float64))
    fs.write("dist_coeffs", np.asarray(camera.dist, dtype=np.float64).reshape(1, 5))
    fs.write("image_width", int(camera.width))
    fs.write("image_height", int(camera.height))
    fs.write("model", camera.model)
    fs.write("name", camera.name)
    if camera.pixel_pitch is not None:
        fs.write("pixel_pitch_mm", float(camera.pixel_pitch * 1e3))
    for block, values in thesis_blocks(camera).items():
        fs.startWriteStruct(block, cv2.FILE_NODE_MAP)
        for key, val in values.items():
            fs.write(key, float(val))
        fs.endWriteStruct()
    if extra:
        fs.startWriteStruct("extra", cv2.FILE_NODE_MAP)
        for key, val in extra.items():
            if isinstance(val, str):
                fs.write(str(key), val)
            elif isinstance(val, (int, float, np.integer, np.floating)) and not isinstance(val, bool) \
                    and np.isfinite(val):
                fs.write(str(key), float(val))
            else:
                raise ValueError(f"extra.{key}: expected a finite number or a string, got {val!r}")
        fs.endWriteStruct()
    if port is not None:
        fs.startWriteStruct("flat_port", cv2.FILE_NODE_MAP)
        for key in _FlatPortBlock.model_fields:
            fs.write(key, float(port[key]))
        fs.endWriteStruct()
    return fs.releaseAndGetString()


def write_camera_yaml(path, camera, extra: dict | None = None) -> Path:
    """Write ``camera.yaml`` atomically (temporary file in the same folder, then rename); returns the path."""
    return atomic_write_text(path, camera_yaml_text(camera, extra))  # a plain file's permissions (umask)


def _plain(node):
    """A ``cv2.FileNode`` as plain Python: mappings, lists, numbers, strings; an ``!!opencv-matrix`` as a list of
    rows (or of values, for one row)."""
    if node.isMap():
        keys = list(node.keys())
        if {"rows", "cols", "dt", "data"} <= set(keys):
            mat = node.mat()
            if mat is not None:
                return np.asarray(mat, dtype=float).tolist()
        return {k: _plain(node.getNode(k)) for k in keys}
    if node.isSeq():
        return [_plain(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def _matrix(value):
    """A matrix: a list of numbers or of equally long rows of numbers (non-finite values are the camera's to
    refuse: :class:`~bench.camera.model.CameraModel` names them)."""
    rows = value if isinstance(value, list) else None
    if not rows or not all(isinstance(r, list) and r or _is_number(r) for r in rows):
        raise PydanticCustomError("matrix", "expected a matrix (!!opencv-matrix or a list of numbers)")
    if any(isinstance(r, list) for r in rows):
        if not all(isinstance(r, list) and all(_is_number(x) for x in r) for r in rows):
            raise PydanticCustomError("matrix", "expected a matrix (!!opencv-matrix or a list of numbers)")
        if len({len(r) for r in rows}) != 1:
            raise PydanticCustomError("matrix", "rows of unequal length")
    return value


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _number_or_text(value):
    if isinstance(value, str):
        return value
    if not _is_number(value) or not np.isfinite(value):
        raise PydanticCustomError("number_type", "expected a number")
    return value


Matrix = Annotated[list, PlainValidator(_matrix)]
_POSITIVE_PX = at_least(1, "expected a positive integer (px), got {v}")


class _HeikkilaBlock(Heikkila75):
    """``heikkila_eq75`` as written beside the matrices: the specification's block and the focal length in mm."""

    f_mm: float


class _FlatPortBlock(Section):
    lens_to_glass_mm: float
    glass_thickness_mm: float
    n_air: float
    n_glass: float
    n_water: float
    tilt_x_deg: float
    tilt_y_deg: float
    working_range_m: float


class CameraFile(Section):
    """``camera.yaml`` (module docstring); the keys of OpenCV's calibration sample are accepted and ignored."""

    camera_matrix: Matrix
    dist_coeffs: Matrix | None = None
    distortion_coefficients: Matrix | None = None  # OpenCV's calibration sample's name of dist_coeffs
    image_width: Annotated[int, _POSITIVE_PX]
    image_height: Annotated[int, _POSITIVE_PX]
    model: str | None = None
    name: str | None = None
    pixel_pitch_mm: float | None = None
    intrinsics_eq50: Eq50 | None = None
    heikkila_eq75: _HeikkilaBlock | None = None
    extra: dict[str, Annotated[Any, PlainValidator(_number_or_text)]] = {}
    flat_port: _FlatPortBlock | None = None

    @model_validator(mode="before")
    @classmethod
    def _sample_keys(cls, data):
        return {k: v for k, v in data.items() if k not in _OPENCV_SAMPLE_KEYS or k in cls.model_fields} \
            if isinstance(data, dict) else data

    @model_validator(mode="after")
    def _distortion(self):
        if self.dist_coeffs is None and self.distortion_coefficients is None:
            raise KeyProblem("dist_coeffs", "missing")
        return self


def _check_block(src, block, values: dict, expected: dict | None):
    """A derived block read back must agree with the camera its matrices make."""
    if expected is None:
        raise ConfigError(src, block, "present, but the camera has no such form (needs pixel_pitch_mm, no skew, "
                                      "no k3)")
    for k, val in values.items():
        ref = expected[k]
        if abs(val - ref) > _CONSISTENCY_RTOL * max(abs(ref), 1e-12) + 1e-15:
            raise ConfigError(src, f"{block}.{k}", f"{val!r} disagrees with camera_matrix/dist_coeffs ({ref!r})")


def read_camera_yaml(path, with_extra: bool = False, allow_refractive: bool = False):
    """Read ``camera.yaml`` (ours, or one written by OpenCV) into a :class:`CameraModel`.

    Parameters
    ----------
    path : str or Path
    with_extra : bool
        Also return the ``extra`` mapping (``{}`` when absent).
    allow_refractive : bool
        Accept a ``flat_port`` block (then a :class:`~bench.camera.refractive.RefractiveCamera` is returned); where
        it is not accepted, the block is a one-line error naming it.

    Returns
    -------
    camera : CameraModel or RefractiveCamera
        ``name`` defaults to the file's parent folder name, ``model`` to the one derived from the coefficients.
    extra : dict, only with ``with_extra``
    """
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise ConfigError(src, "file", "not found")
    try:
        fs = cv2.FileStorage(src, cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV's parser errors arrive as cv2.error wrapped in SystemError
        raise ConfigError(src, "file", _unreadable(path, exc)) from None
    try:
        if not fs.isOpened():
            raise ConfigError(src, "file", "cannot be opened")
        root = fs.root()
        if not root.isMap():
            raise ConfigError(src, "<top>", "expected a mapping")
        data = _plain(root)
    finally:
        fs.release()
    cfg = parse(CameraFile, data, src)
    dist_key = "dist_coeffs" if cfg["dist_coeffs"] is not None else "distortion_coefficients"
    K = np.asarray(cfg["camera_matrix"], dtype=float)
    if K.shape != (3, 3):
        raise ConfigError(src, "camera_matrix", f"expected 3x3, got shape {K.shape}")
    dist = np.asarray(cfg[dist_key], dtype=float).ravel()
    name = cfg["name"] if cfg["name"] is not None else (path.parent.name or "camera")
    pitch = None if cfg["pixel_pitch_mm"] is None else cfg["pixel_pitch_mm"] * 1e-3
    try:
        camera = CameraModel(cfg["image_width"], cfg["image_height"], K, dist, name=name, model=cfg["model"],
                             pixel_pitch=pitch)
    except ValueError as exc:
        field, _, problem = str(exc).partition(": ")
        field = {"K": "camera_matrix", "dist": dist_key, "pixel_pitch": "pixel_pitch_mm"}.get(field, field)
        raise ConfigError(src, field, problem or str(exc)) from None
    derived = thesis_blocks(camera)
    for block in ("intrinsics_eq50", "heikkila_eq75"):
        if cfg[block] is not None:
            _check_block(src, block, cfg[block], derived.get(block))
    extra = {k: v if isinstance(v, str) else float(v) for k, v in cfg["extra"].items()}
    if cfg["flat_port"] is not None:
        if not allow_refractive:
            raise ConfigError(src, "flat_port", "a refractive camera (lens behind a flat port) is not supported "
                                                "here: only the in-situ localisation (bench locate) takes one")
        camera = _refractive(src, cfg["flat_port"], camera)
    return (camera, extra) if with_extra else camera


def _unreadable(path: Path, exc) -> str:
    """Why OpenCV could not read ``path`` as a camera file: another file given in its place (a YAML mapping without
    ``camera_matrix``, e.g. a robot file) is named by its keys; else OpenCV's own last line."""
    import yaml

    try:
        doc = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError, OSError):
        doc = None
    if isinstance(doc, dict) and "camera_matrix" not in doc:
        keys = ", ".join(str(k) for k in list(doc)[:5]) + (", ..." if len(doc) > 5 else "")
        return f"not a camera file: a YAML mapping of {keys} without camera_matrix"
    cause = exc.__cause__ or exc.__context__ or exc
    lines = [ln.strip() for ln in str(cause).splitlines() if ln.strip()]
    return f"not a readable OpenCV YAML/XML/JSON file ({lines[-1] if lines else 'parse error'})"


def _refractive(src, v: dict, lens):
    from bench.camera.flatport import FlatPort
    from bench.camera.refractive import RefractiveCamera

    try:
        port = FlatPort(d0=v["lens_to_glass_mm"] * 1e-3, t=v["glass_thickness_mm"] * 1e-3, n_air=v["n_air"],
                        n_glass=v["n_glass"], n_water=v["n_water"],
                        tilt=np.deg2rad([v["tilt_x_deg"], v["tilt_y_deg"]]), source=src)
        return RefractiveCamera(lens, port, v["working_range_m"], name=lens.name)
    except (ConfigError, ValueError) as exc:
        field, problem = (exc.field, exc.problem) if isinstance(exc, ConfigError) else str(exc).partition(": ")[::2]
        field = {"d0": "lens_to_glass_mm", "t": "glass_thickness_mm", "tilt": "tilt_x_deg"}.get(field, field)
        raise ConfigError(src, f"flat_port.{field}", problem or str(exc)) from None



# ------------------------------------------------------------------------------------------------ housing.yaml

#: ``housing.yaml``: the underwater housing's datasheet and the site's water, what a refractive calibration starts
#: from and holds fixed (lens_to_glass_mm is the design value, a start: the calibration estimates it)
_INDEX_PROBLEM = "expected a refractive index in [1, 2.5], got {v}"
_INDEX = Annotated[float, at_least(1, _INDEX_PROBLEM), at_most(2.5, _INDEX_PROBLEM)]


class HousingFile(Section):
    """``housing.yaml`` (every key required)."""

    lens_to_glass_mm: Annotated[float, Field(ge=1, le=500)]
    lens_to_glass_tolerance_mm: PositiveFloat
    glass_thickness_mm: Annotated[float, Field(ge=0, le=100)]
    n_air: _INDEX
    n_glass: _INDEX
    n_water: _INDEX

    @model_validator(mode="after")
    def _tolerance(self):
        if not self.lens_to_glass_tolerance_mm < self.lens_to_glass_mm:
            raise KeyProblem("lens_to_glass_tolerance_mm", f"expected below lens_to_glass_mm, got "
                                                           f"{self.lens_to_glass_tolerance_mm}")
        return self


def housing_yaml_text(port, tolerance_mm: float) -> str:
    """The text of ``housing.yaml`` for a nominal :class:`~bench.camera.flatport.FlatPort` and the stated tolerance
    (mm, +-) of its lens-to-glass distance - lens entrance pupil to the inner glass surface, which a drawing gives
    only roughly (the tilt and decentre, manufacturing errors, are not part of a datasheet and are not written)."""
    return (f"# the camera housing's datasheet and the site's water (refractive calibration: bench.camera.refractive)\n"
            f"lens_to_glass_mm: {port.d0 * 1e3:.6g}\nlens_to_glass_tolerance_mm: {tolerance_mm:.6g}\n"
            f"glass_thickness_mm: {port.t * 1e3:.6g}\n"
            f"n_air: {port.n_air:.6g}\nn_glass: {port.n_glass:.6g}\nn_water: {port.n_water:.6g}\n")


def read_housing_yaml(path):
    """``(port, d0_sigma_m)``: the nominal :class:`~bench.camera.flatport.FlatPort` of a ``housing.yaml`` (no tilt)
    and the standard deviation of its lens-to-glass distance (m), the stated tolerance taken as uniform (``tol /
    sqrt(3)``); a missing file, key or a bad value is a one-line error naming the file and the key."""
    from bench.camera.flatport import FlatPort

    src = str(path)
    spec = read_yaml(path, "missing: a refractive camera model needs the housing's datasheet "
                           f"({', '.join(HousingFile.model_fields)})")
    v = parse(HousingFile, spec, src)
    port = FlatPort(d0=v["lens_to_glass_mm"] * 1e-3, t=v["glass_thickness_mm"] * 1e-3, n_air=v["n_air"],
                    n_glass=v["n_glass"], n_water=v["n_water"], source=src)
    return port, v["lens_to_glass_tolerance_mm"] * 1e-3 / np.sqrt(3.0)
