"""Housing and medium parts of the simulator's optics presets (issue 3 item 4).

A preset names the camera specifications (:mod:`bench.camera.presets`) and the physical parts in front of and around
the lens:

* ``air_webcam`` - Table 3 webcam, no port, no water; sensor noise only;
* ``underwater_in_air`` - the underwater camera's housing in air (§5.3, Table 9): the glass slab only
  (``n_water = n_air``, it shifts rays laterally), sensor noise, and the lab's frame grabber: the analog camera's
  signal sampled at 320 x 240 px by a Pinnacle PCTV card and interpolated to 640 x 480 (``sensor.digitiser_px``,
  applied by the realistic profile's ``frame_grabber`` stage);
* ``underwater_in_water`` - the same housing submerged (§5.5, Table 15): flat port into sea water, ``coastal`` water,
  a co-located lamp, sensor noise, automatic exposure (the lamp and the water make the scene's brightness depend on
  the range; a camera on an ROV exposes for the scene, see :class:`bench.sim.medium.Sensor`). Its output is
  digital at 640 x 480 (the TA-40's camera on a dive, not the 2008 lab's frame grabber: ``sensor.digitiser_px``
  puts one in front of it).

``lens_camera`` is the camera *inside* the housing (used by :class:`bench.sim.flatport.FlatPortStage` as its lens,
its distortion applied in ray space before the port); ``nominal_camera`` is the specification the pipeline is given
(the thesis's calibration of the whole system). For the submerged camera these differ: the thesis's Table 15 focal
length is 662.6 / 510.06 = 1.30 times Table 9's, close to the flat port's paraxial magnification ``n_water / n_air``
= 1.34 - the port makes the difference. The housing geometry of the MCH-3000P is not given in the thesis: the values
below (20 mm lens-to-glass, 12 mm crown glass, a ~1 deg misalignment - the thesis notes the camera "was not aligned
with the glass", §5.3) are plausible choices, stated as such.

Every preset is a plain nested dict with the unit in each key (:data:`PRESET_CONFIGS`, :func:`preset_config`);
:func:`optics_from_config` validates one and builds the stages, so a scenario can override any field
(``optics_preset(name, overrides={"port": {"glass_thickness_mm": 8}})``). Unknown keys and impossible optics
(negative thickness, index < 1, a lamp at zero range...) are one-line :class:`~bench.errors.ConfigError` naming the
field (``port.glass_thickness_mm``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from bench.camera.flatport import FlatPort
from bench.config import KeyProblem, Section, parse
from bench.errors import ConfigError
from bench.sim.medium import WATER_PRESETS, Light, MediumChain, Sensor, WaterMedium

#: refractive indices: air 1.000, crown glass (BK7-like) ~1.52, sea water ~1.34 (visible band, 20 C, 35 PSU)
N_AIR, N_GLASS, N_SEAWATER = 1.0, 1.52, 1.34

_HOUSING = {"lens_to_glass_mm": 20.0, "glass_thickness_mm": 12.0, "n_air": N_AIR, "n_glass": N_GLASS,
            "tilt_deg": [0.86, -0.69], "decentre_mm": [1.0, -0.5]}
#: a sensor with 10 000 e- full well mapped to 255 DN and 5 e- read noise (a typical small CMOS), lossless output
_SENSOR = {"full_well_e": 10000.0, "exposure": 1.0, "gain_dn_per_e": 255.0 / 10000.0, "read_noise_e": 5.0,
           "jpeg_quality": 0}

#: the submerged camera exposes automatically (the ROV camera's auto exposure): the mean grey value of each frame is
#: brought to 40 % of full scale (102 DN at 8 bit; FLIR's "target grey value" and Basler's "target brightness" are of
#: this kind; 40 % rather than 50 % keeps the white tags and the dial faces under the lamp below saturation, < 1 % of
#: the pixels of a panel view at 0.7-1.0 m), by exposure times up to 8x the reference (3 stops: the lamp's range
#: fall-off and the water's attenuation between 0.7 and 1.3 m of standoff are about 1-2 stops)
_SENSOR_AUTO = {**_SENSOR, "auto_exposure_target": 0.4, "auto_exposure_max": 8.0}

#: The presets as unit-keyed dicts (``port``/``water``/``light``/``sensor`` may be None = absent).
PRESET_CONFIGS = {
    "air_webcam": {"nominal_camera": "air_webcam", "lens_camera": "air_webcam", "port": None, "water": None,
                   "light": None, "sensor": _SENSOR},
    "underwater_in_air": {"nominal_camera": "underwater_in_air", "lens_camera": "underwater_in_air",
                          "port": {**_HOUSING, "n_water": N_AIR}, "water": None, "light": None,
                          "sensor": {**_SENSOR, "digitiser_px": [320, 240]}},
    "underwater_in_water": {"nominal_camera": "underwater_in_water", "lens_camera": "underwater_in_air",
                            "port": {**_HOUSING, "n_water": N_SEAWATER}, "water": {"preset": "coastal"},
                            "light": {"ref_range_m": 1.0, "beam_exponent": 2.0, "ambient": 0.15,
                                      "attenuate_outgoing": True, "position_m": [0.0, 0.0, 0.0],
                                      "axis": [0.0, 0.0, 1.0]},
                            "sensor": _SENSOR_AUTO},
}



@dataclass(frozen=True)
class OpticsPreset:
    """Housing and medium of a simulated camera.

    Attributes
    ----------
    name : str
    nominal_camera : str
        Camera preset the pipeline receives (:func:`bench.camera.presets.load_preset`).
    lens_camera : str
        Camera preset of the lens inside the housing (the render/distortion camera).
    port : FlatPort or None
        None: no port (the lens camera sees the scene directly).
    chain : MediumChain
        Water, lamp and sensor stages (:func:`bench.sim.medium.apply_medium`).
    """

    name: str
    nominal_camera: str
    lens_camera: str
    port: FlatPort | None
    chain: MediumChain


def optics_preset_names() -> list[str]:
    """Names of the optics presets, sorted."""
    return sorted(PRESET_CONFIGS)


def preset_config(name: str) -> dict:
    """A deep copy of the unit-keyed config of preset ``name``; unknown -> one-line ``ValueError`` listing them."""
    if not isinstance(name, str) or name not in PRESET_CONFIGS:
        raise ValueError(f"optics preset: unknown {name!r} (known: {', '.join(optics_preset_names())})")
    return copy.deepcopy(PRESET_CONFIGS[name])


def optics_preset(name: str, overrides: dict | None = None) -> OpticsPreset:
    """The :class:`OpticsPreset` called ``name``, optionally with some fields replaced.

    Parameters
    ----------
    name : str
        One of :func:`optics_preset_names`; unknown -> one-line ``ValueError`` listing the known ones.
    overrides : dict, optional
        Nested dict merged into the preset's config (same keys as :data:`PRESET_CONFIGS`): the fields given in a
        ``port``/``light``/``sensor`` section replace the preset's; a ``water`` section replaces the preset's whole
        (a ``preset`` name or all four coefficients); a section set to None removes it.
    """
    cfg = preset_config(name)
    source = f"optics preset {name!r}"
    if overrides is not None:
        if not isinstance(overrides, dict):
            raise ConfigError(source, "overrides", f"expected a mapping, got {type(overrides).__name__}")
        for key, val in overrides.items():
            if key not in _Optics.model_fields:
                raise ConfigError(source, str(key), f"unknown key (known: {', '.join(_Optics.model_fields)})")
            if isinstance(val, dict) and isinstance(cfg.get(key), dict) and key != "water":
                cfg[key] = {**cfg[key], **val}
            else:
                cfg[key] = copy.deepcopy(val)
    return optics_from_config(cfg, source, name)


# ----------------------------------------------------------------------------------------------------------------------
# validation and construction
# ----------------------------------------------------------------------------------------------------------------------
_INDEX = Annotated[float, Field(ge=1)]


def _floats(n: int, lo: float | None = None, hi: float | None = None):
    """A list of ``n`` finite floats, each within ``[lo, hi]``."""
    return Annotated[list[Annotated[float, Field(ge=lo, le=hi)]], Field(min_length=n, max_length=n)]


class _Port(Section):
    lens_to_glass_mm: Annotated[float, Field(gt=0, le=1000)]
    glass_thickness_mm: Annotated[float, Field(ge=0, le=1000)]
    n_air: _INDEX
    n_glass: _INDEX
    n_water: _INDEX
    tilt_deg: _floats(2, -44.9, 44.9)
    decentre_mm: _floats(2, -999, 999)


class _Water(Section):
    """A preset's name, or all four coefficients."""

    preset: Literal[tuple(WATER_PRESETS)] | None = None
    beta_D_per_m: _floats(3, 0, 50) | None = None
    beta_B_per_m: _floats(3, 0, 50) | None = None
    B_inf: _floats(3, 0, 1) | None = None
    forward_scatter_px_per_m: Annotated[float, Field(ge=0, le=100)] | None = None

    @model_validator(mode="after")
    def _preset_or_coefficients(self):
        coefficients = [k for k in type(self).model_fields if k != "preset"]
        given = [k for k in coefficients if getattr(self, k) is not None]
        if self.preset is not None and given:
            raise KeyProblem(given[0], "give either a preset or the coefficients, not both")
        missing = [k for k in coefficients if k not in given]
        if self.preset is None and missing:
            raise KeyProblem(missing[0], "missing")
        return self


class _Light(Section):
    ref_range_m: Annotated[float, Field(gt=0, le=1e3)]
    beam_exponent: Annotated[float, Field(ge=0, le=1e3)]
    ambient: Annotated[float, Field(ge=0, le=1e3)]
    attenuate_outgoing: bool = True
    position_m: _floats(3, -10, 10) = [0.0, 0.0, 0.0]
    axis: _floats(3) = [0.0, 0.0, 1.0]

    @model_validator(mode="after")
    def _axis(self):
        if np.linalg.norm(self.axis) < 1e-9:
            raise KeyProblem("axis", "must be a non-zero vector")
        return self


class _Sensor(Section):
    full_well_e: Annotated[float, Field(ge=1, le=1e8)]
    exposure: Annotated[float, Field(gt=0, le=1e6)]
    gain_dn_per_e: Annotated[float, Field(gt=0, le=1e3)]
    read_noise_e: Annotated[float, Field(ge=0, le=1e6)]
    jpeg_quality: Annotated[int, Field(ge=0, le=100)] = 0  # 0 = off
    auto_exposure_target: Annotated[float, Field(ge=0, le=1)] | None = None  # optional: manual exposure without them
    auto_exposure_max: Annotated[float, Field(gt=0, le=1e6)] | None = None
    digitiser_px: Annotated[list[Annotated[int, Field(ge=8, le=100000)]], Field(min_length=2, max_length=2)] | None \
        = None  # an analog camera's frame grabber (w, h); None: a digital camera


class _Optics(Section):
    """The layout of :data:`PRESET_CONFIGS` (a section set to None is absent)."""

    nominal_camera: Annotated[str, Field(min_length=1)]
    lens_camera: Annotated[str, Field(min_length=1)]
    port: _Port | None = None
    water: _Water | None = None
    light: _Light | None = None
    sensor: _Sensor | None = None


def optics_from_config(cfg: dict, source: str = "optics", name: str = "custom") -> OpticsPreset:
    """Validate a unit-keyed optics config (the layout of :data:`PRESET_CONFIGS`) and build the stages.

    Lengths in the ``port`` section are in mm, angles in degrees, converted to SI here; the other sections are SI
    with units in the keys. A water medium requires a port with ``n_water != n_air`` (the water is outside the
    housing); a submerged port without a water section refracts but leaves the colours alone.

    Raises
    ------
    ConfigError
        One line naming ``source`` and the field (``port.glass_thickness_mm``, ``water.beta_D_per_m``...).
    """
    c = parse(_Optics, cfg, source)
    port = None
    if c["port"] is not None:
        p = c["port"]
        try:
            port = FlatPort(d0=p["lens_to_glass_mm"] * 1e-3, t=p["glass_thickness_mm"] * 1e-3, n_air=p["n_air"],
                            n_glass=p["n_glass"], n_water=p["n_water"], tilt=np.deg2rad(p["tilt_deg"]),
                            decentre=np.array(p["decentre_mm"]) * 1e-3, source=source)
        except ConfigError as exc:  # geometry that only the combination makes impossible (the plane behind the centre)
            field = {"d0": "lens_to_glass_mm", "t": "glass_thickness_mm", "tilt": "tilt_deg",
                     "decentre": "decentre_mm"}.get(exc.field, exc.field)
            raise ConfigError(source, f"port.{field}", exc.problem) from None
    w = c["water"]
    medium = None if w is None else WaterMedium(name=w["preset"], **WATER_PRESETS[w["preset"]]) if w["preset"] \
        else WaterMedium(name="custom", **{k: v for k, v in w.items() if k != "preset"})
    if medium is not None and (port is None or port.n_water == port.n_air):
        raise ConfigError(source, "water", "a water medium needs a port with n_water (the outside) != n_air")
    light = None if c["light"] is None else Light(**c["light"])
    sensor = None if c["sensor"] is None else Sensor(**{k: v for k, v in c["sensor"].items() if v is not None})
    return OpticsPreset(name, c["nominal_camera"], c["lens_camera"], port,
                        MediumChain(medium=medium, light=light, sensor=sensor))
