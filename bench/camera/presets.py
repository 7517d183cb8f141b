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
from typing import Annotated, Literal

import numpy as np
from pydantic import model_validator

from bench.camera.dlt import intrinsic_matrix
from bench.camera.heikkila import HeikkilaParameters, camera_from_heikkila
from bench.camera.model import CameraModel
from bench.config import KeyProblem, PositiveFloat, PositiveInt, Section, at_least, at_most, parse
from bench.errors import ConfigError
from bench.fileio import read_yaml

_SKEW = "skew angle {v} deg is implausible (expected near 90; radians given?)"


class Eq50(Section):
    """``intrinsics_eq50``: the thesis's Eq. 50 intrinsics."""

    alpha_px: PositiveFloat
    beta_px: PositiveFloat
    theta_deg: Annotated[float, at_least(45, _SKEW, strict=True), at_most(135, _SKEW, strict=True)]
    u0_px: float
    v0_px: float


class Heikkila75(Section):
    """``heikkila_eq75``: Heikkilä's parameters in the thesis's units (:mod:`bench.camera.heikkila`)."""

    s_u: PositiveFloat
    f_px: PositiveFloat
    u0_px: float
    v0_px: float
    k1_per_mm2: float
    k2_per_mm4: float
    T1_per_mm: float
    T2_per_mm: float
    pixels_per_mm: PositiveFloat


class CameraSpec(Section):
    """A camera specification file (``models/cameras/*.yaml``): exactly one of the two intrinsics blocks."""

    name: str
    source: str = ""
    image_width_px: PositiveInt
    image_height_px: PositiveInt
    intrinsics_eq50: Eq50 | None = None
    distortion: Literal["none"] | None = None  # with intrinsics_eq50 (heikkila_eq75 holds its own distortion)
    heikkila_eq75: Heikkila75 | None = None
    reprojection_chi_px: float | None = None

    @model_validator(mode="after")
    def _one_block(self):
        if (self.intrinsics_eq50 is None) == (self.heikkila_eq75 is None):
            raise KeyProblem("intrinsics_eq50/heikkila_eq75", "exactly one of the two blocks is required")
        if self.intrinsics_eq50 is not None and self.distortion is None:
            raise KeyProblem("distortion", "expected 'none' with intrinsics_eq50")
        if self.heikkila_eq75 is not None and self.distortion is not None:
            raise KeyProblem("distortion", "not allowed with heikkila_eq75 (the block holds the distortion)")
        return self


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


def load_camera_spec(path) -> CameraModel:
    """Read a camera specification file (the format of ``models/cameras/*.yaml``) into a :class:`CameraModel`."""
    src = str(path)
    doc = parse(CameraSpec, read_yaml(path), src)
    size, name = (doc["image_width_px"], doc["image_height_px"]), doc["name"]
    try:
        if doc["intrinsics_eq50"] is not None:
            b = doc["intrinsics_eq50"]
            K = intrinsic_matrix(b["alpha_px"], b["beta_px"], np.deg2rad(b["theta_deg"]), b["u0_px"], b["v0_px"])
            if b["theta_deg"] == 90.0:
                K[0, 1] = 0.0  # cot(pi/2) is 6e-17 in floating point, not 0
            return CameraModel(size[0], size[1], K, np.zeros(5), name=name, model="pinhole")
        v = doc["heikkila_eq75"]
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
