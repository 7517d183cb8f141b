"""Named camera specifications transcribed from the thesis (``models/cameras/*.yaml``) and their loader.

* ``air_webcam`` - Table 3 average intrinsics (Eq. 50), no distortion, 640 x 480;
* ``underwater_in_air`` - Table 9, Heikkilä's model (Eq. 75-76), 640 x 480;
* ``underwater_in_water`` - Table 15, Heikkilä's model, 640 x 480.

A spec file has units in its keys (``alpha_px``, ``theta_deg``, ``k1_per_mm2``...) and is converted to SI here, at the
boundary. Either an ``intrinsics_eq50`` block (``alpha_px, beta_px, theta_deg, u0_px, v0_px``) with
``distortion: none`` or a ``heikkila_eq75`` block (``s_u, f_px, u0_px, v0_px, k1_per_mm2, k2_per_mm4, T1_per_mm,
T2_per_mm, pixels_per_mm``, see :mod:`bench.camera.heikkila` for the units). Malformed files are one-line
:class:`~bench.errors.ConfigError` naming the file and the key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from bench.camera.dlt import intrinsic_matrix
from bench.camera.heikkila import HeikkilaParameters, camera_from_heikkila
from bench.camera.model import CameraModel
from bench.errors import ConfigError

_TOP_KEYS = {"name", "source", "image_width_px", "image_height_px", "intrinsics_eq50", "distortion",
             "heikkila_eq75", "reprojection_chi_px"}
_EQ50_KEYS = ("alpha_px", "beta_px", "theta_deg", "u0_px", "v0_px")
_HEIKKILA_KEYS = ("s_u", "f_px", "u0_px", "v0_px", "k1_per_mm2", "k2_per_mm4", "T1_per_mm", "T2_per_mm",
                  "pixels_per_mm")


def presets_dir() -> Path:
    """The folder of the shipped camera specifications (``models/cameras``)."""
    return Path(__file__).resolve().parents[2] / "models" / "cameras"


def preset_names() -> list[str]:
    """Names of the shipped presets (file stems in :func:`presets_dir`), sorted."""
    return sorted(p.stem for p in presets_dir().glob("*.yaml"))


def preset_path(name: str) -> Path:
    """Path of preset ``name``; unknown name -> one-line ``ValueError`` listing the known ones."""
    names = preset_names()
    if not isinstance(name, str) or name not in names:
        raise ValueError(f"camera preset: unknown {name!r} (known: {', '.join(names)})")
    return presets_dir() / f"{name}.yaml"


def load_preset(name: str) -> CameraModel:
    """The :class:`CameraModel` of a shipped preset (see the module docstring)."""
    return load_camera_spec(preset_path(name))


def _number(src, key, value, positive=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(src, key, f"expected a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise ConfigError(src, key, "must be finite")
    if positive and value <= 0:
        raise ConfigError(src, key, f"must be > 0, got {value}")
    return value


def _block(src, doc, key, names):
    block = doc[key]
    if not isinstance(block, dict):
        raise ConfigError(src, key, "expected a mapping")
    unknown = set(block) - set(names)
    if unknown:
        raise ConfigError(src, f"{key}.{sorted(unknown)[0]}", f"unknown key (allowed: {', '.join(names)})")
    for n in names:
        if n not in block:
            raise ConfigError(src, f"{key}.{n}", "missing")
    return block


def load_camera_spec(path) -> CameraModel:
    """Read a camera specification file (the format of ``models/cameras/*.yaml``) into a :class:`CameraModel`."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise ConfigError(src, "file", "not found")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(src, "file", f"not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise ConfigError(src, "<top>", "expected a mapping")
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        raise ConfigError(src, sorted(unknown)[0], f"unknown key (allowed: {', '.join(sorted(_TOP_KEYS))})")
    for key in ("name", "image_width_px", "image_height_px"):
        if key not in doc:
            raise ConfigError(src, key, "missing")
    size = []
    for key in ("image_width_px", "image_height_px"):
        val = doc[key]
        if isinstance(val, bool) or not isinstance(val, int) or val <= 0:
            raise ConfigError(src, key, f"expected a positive integer, got {val!r}")
        size.append(val)
    name = str(doc["name"])
    has_eq50, has_heik = "intrinsics_eq50" in doc, "heikkila_eq75" in doc
    if has_eq50 == has_heik:
        raise ConfigError(src, "intrinsics_eq50/heikkila_eq75", "exactly one of the two blocks is required")
    try:
        if has_eq50:
            if doc.get("distortion") != "none":
                raise ConfigError(src, "distortion", f"expected 'none' with intrinsics_eq50, got "
                                                     f"{doc.get('distortion')!r}")
            b = _block(src, doc, "intrinsics_eq50", _EQ50_KEYS)
            alpha, beta = (_number(src, f"intrinsics_eq50.{k}", b[k], positive=True) for k in ("alpha_px", "beta_px"))
            theta_deg = _number(src, "intrinsics_eq50.theta_deg", b["theta_deg"])
            if not 45.0 < theta_deg < 135.0:
                raise ConfigError(src, "intrinsics_eq50.theta_deg", f"skew angle {theta_deg} deg is implausible "
                                                                    "(expected near 90; radians given?)")
            u0, v0 = (_number(src, f"intrinsics_eq50.{k}", b[k]) for k in ("u0_px", "v0_px"))
            theta = np.deg2rad(theta_deg)
            K = intrinsic_matrix(alpha, beta, theta, u0, v0)  # Eq. 50
            if theta_deg == 90.0:
                K[0, 1] = 0.0  # cot(pi/2) is 6e-17 in floating point, not 0
            return CameraModel(size[0], size[1], K, np.zeros(5), name=name, model="pinhole")
        if "distortion" in doc:
            raise ConfigError(src, "distortion", "not allowed with heikkila_eq75 (the block holds the distortion)")
        b = _block(src, doc, "heikkila_eq75", _HEIKKILA_KEYS)
        v = {k: _number(src, f"heikkila_eq75.{k}", b[k], positive=k in ("s_u", "f_px", "pixels_per_mm"))
             for k in _HEIKKILA_KEYS}
        pitch = 1e-3 / v["pixels_per_mm"]  # m per pixel
        mm = 1e-3
        params = HeikkilaParameters(s_u=v["s_u"], f=v["f_px"] * pitch, u0=v["u0_px"], v0=v["v0_px"],
                                    k1=v["k1_per_mm2"] / mm**2, k2=v["k2_per_mm4"] / mm**4, p1=v["T1_per_mm"] / mm,
                                    p2=v["T2_per_mm"] / mm, pixel_pitch=pitch)
        camera = camera_from_heikkila(params, size[0], size[1], name=name)
    except ValueError as exc:
        raise ConfigError(src, "camera", str(exc)) from None
    try:
        camera.check_invertible()
    except ValueError as exc:
        raise ConfigError(src, "heikkila_eq75", str(exc)) from None
    return camera
