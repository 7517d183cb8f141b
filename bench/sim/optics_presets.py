"""Housing and medium parts of the simulator's optics presets (issue 3 item 4).

A preset names the camera specifications (:mod:`bench.camera.presets`) and the physical parts in front of and around
the lens:

* ``air_webcam`` - Table 3 webcam, no port, no water; sensor noise only;
* ``underwater_in_air`` - the underwater camera's housing in air (§5.3, Table 9): the glass slab only
  (``n_water = n_air``, it shifts rays laterally), sensor noise;
* ``underwater_in_water`` - the same housing submerged (§5.5, Table 15): flat port into sea water, ``coastal`` water,
  a co-located lamp, sensor noise, automatic exposure (the lamp and the water make the scene's brightness depend on
  the range; a camera on an ROV exposes for the scene, see :class:`bench.sim.medium.Sensor`).

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

import numpy as np

from bench.camera.flatport import FlatPort
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
                          "port": {**_HOUSING, "n_water": N_AIR}, "water": None, "light": None, "sensor": _SENSOR},
    "underwater_in_water": {"nominal_camera": "underwater_in_water", "lens_camera": "underwater_in_air",
                            "port": {**_HOUSING, "n_water": N_SEAWATER}, "water": {"preset": "coastal"},
                            "light": {"ref_range_m": 1.0, "beam_exponent": 2.0, "ambient": 0.15,
                                      "attenuate_outgoing": True, "position_m": [0.0, 0.0, 0.0],
                                      "axis": [0.0, 0.0, 1.0]},
                            "sensor": _SENSOR_AUTO},
}

_TOP = ("nominal_camera", "lens_camera", "port", "water", "light", "sensor")
_PORT_KEYS = ("lens_to_glass_mm", "glass_thickness_mm", "n_air", "n_glass", "n_water", "tilt_deg", "decentre_mm")
_WATER_KEYS = ("preset", "beta_D_per_m", "beta_B_per_m", "B_inf", "forward_scatter_px_per_m")
_LIGHT_KEYS = ("ref_range_m", "beam_exponent", "ambient", "attenuate_outgoing", "position_m", "axis")
_SENSOR_KEYS = ("full_well_e", "exposure", "gain_dn_per_e", "read_noise_e", "jpeg_quality", "auto_exposure_target",
                "auto_exposure_max")


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
            if key not in _TOP:
                raise ConfigError(source, str(key), f"unknown key (known: {', '.join(_TOP)})")
            if isinstance(val, dict) and isinstance(cfg.get(key), dict) and key != "water":
                cfg[key] = {**cfg[key], **val}
            else:
                cfg[key] = copy.deepcopy(val)
    return optics_from_config(cfg, source, name)


# ----------------------------------------------------------------------------------------------------------------------
# validation and construction
# ----------------------------------------------------------------------------------------------------------------------
def _section(cfg, key, known, source):
    sec = cfg.get(key)
    if sec is None:
        return None
    if not isinstance(sec, dict):
        raise ConfigError(source, key, f"expected a mapping or null, got {type(sec).__name__}")
    for k in sec:
        if k not in known:
            raise ConfigError(source, f"{key}.{k}", f"unknown key (known: {', '.join(known)})")
    return sec


def _get(sec, section, key, source, *, size=None, lo=None, lo_open=False, hi=None):
    field = f"{section}.{key}"
    if key not in sec:
        raise ConfigError(source, field, "missing")
    val = sec[key]
    arr = np.asarray(val, dtype=object)
    if size is None and arr.ndim != 0 or size is not None and arr.shape != (size,):
        what = "a number" if size is None else f"a list of {size} numbers"
        raise ConfigError(source, field, f"expected {what}, got {val!r}")
    items = arr.reshape(-1)
    for v in items:
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
            raise ConfigError(source, field, f"expected finite numbers, got {val!r}")
    out = np.array(items, dtype=float)
    if lo is not None and (np.any(out < lo) or lo_open and np.any(out == lo)):
        raise ConfigError(source, field, f"must be {'>' if lo_open else '>='} {lo:g}, got {val!r}")
    if hi is not None and np.any(out > hi):
        raise ConfigError(source, field, f"must be <= {hi:g}, got {val!r}")
    return float(out[0]) if size is None else out


def _port(sec, source):
    g = {k: _get(sec, "port", k, source, lo=1.0) for k in ("n_air", "n_glass", "n_water")}
    d0 = _get(sec, "port", "lens_to_glass_mm", source, lo=0.0, lo_open=True, hi=1000.0) * 1e-3
    t = _get(sec, "port", "glass_thickness_mm", source, lo=0.0, hi=1000.0) * 1e-3
    tilt = np.deg2rad(_get(sec, "port", "tilt_deg", source, size=2, lo=-44.9, hi=44.9))
    dec = _get(sec, "port", "decentre_mm", source, size=2, lo=-999.0, hi=999.0) * 1e-3
    try:
        return FlatPort(d0=d0, t=t, tilt=tilt, decentre=dec, source=source, **g)
    except ConfigError as exc:  # geometry that only the combination makes impossible (the plane behind the centre)
        field = {"d0": "lens_to_glass_mm", "t": "glass_thickness_mm", "tilt": "tilt_deg",
                 "decentre": "decentre_mm"}.get(exc.field, exc.field)
        raise ConfigError(source, f"port.{field}", exc.problem) from None


def _water(sec, source):
    if "preset" in sec:
        extra = [k for k in sec if k != "preset"]
        if extra:
            raise ConfigError(source, f"water.{extra[0]}", "give either a preset or the coefficients, not both")
        name = sec["preset"]
        if not isinstance(name, str) or name not in WATER_PRESETS:
            raise ConfigError(source, "water.preset",
                              f"unknown {name!r} (known: {', '.join(sorted(WATER_PRESETS))})")
        return WaterMedium(name=name, **WATER_PRESETS[name])
    vals = {k: _get(sec, "water", k, source, size=3, lo=0.0, hi=50.0) for k in ("beta_D_per_m", "beta_B_per_m")}
    vals["B_inf"] = _get(sec, "water", "B_inf", source, size=3, lo=0.0, hi=1.0)
    vals["forward_scatter_px_per_m"] = _get(sec, "water", "forward_scatter_px_per_m", source, lo=0.0, hi=100.0)
    return WaterMedium(name="custom", **vals)


def _light(sec, source):
    att = sec.get("attenuate_outgoing", True)
    if not isinstance(att, bool):
        raise ConfigError(source, "light.attenuate_outgoing", f"expected true or false, got {att!r}")
    axis = _get(sec, "light", "axis", source, size=3) if "axis" in sec else np.array([0.0, 0.0, 1.0])
    if np.linalg.norm(axis) < 1e-9:
        raise ConfigError(source, "light.axis", "must be a non-zero vector")
    pos = _get(sec, "light", "position_m", source, size=3, lo=-10.0, hi=10.0) if "position_m" in sec else np.zeros(3)
    return Light(ref_range_m=_get(sec, "light", "ref_range_m", source, lo=0.0, lo_open=True, hi=1e3),
                 beam_exponent=_get(sec, "light", "beam_exponent", source, lo=0.0, hi=1e3),
                 ambient=_get(sec, "light", "ambient", source, lo=0.0, hi=1e3),
                 attenuate_outgoing=att, position_m=pos, axis=axis)


def _sensor(sec, source):
    q = sec.get("jpeg_quality", 0)
    if isinstance(q, bool) or not isinstance(q, (int, np.integer)) or not 0 <= q <= 100:
        raise ConfigError(source, "sensor.jpeg_quality", f"expected an integer in 0..100 (0 = off), got {q!r}")
    auto = {k: _get(sec, "sensor", k, source, lo=lo, lo_open=lo_open, hi=hi)
            for k, lo, lo_open, hi in (("auto_exposure_target", 0.0, False, 1.0), ("auto_exposure_max", 0.0, True, 1e6))
            if k in sec}  # optional: manual exposure without them
    return Sensor(full_well_e=_get(sec, "sensor", "full_well_e", source, lo=1.0, hi=1e8),
                  exposure=_get(sec, "sensor", "exposure", source, lo=0.0, lo_open=True, hi=1e6),
                  gain_dn_per_e=_get(sec, "sensor", "gain_dn_per_e", source, lo=0.0, lo_open=True, hi=1e3),
                  read_noise_e=_get(sec, "sensor", "read_noise_e", source, lo=0.0, hi=1e6), jpeg_quality=int(q), **auto)


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
    if not isinstance(cfg, dict):
        raise ConfigError(source, "optics", f"expected a mapping, got {type(cfg).__name__}")
    for k in cfg:
        if k not in _TOP:
            raise ConfigError(source, str(k), f"unknown key (known: {', '.join(_TOP)})")
    cams = {}
    for k in ("nominal_camera", "lens_camera"):
        if not isinstance(cfg.get(k), str) or not cfg[k]:
            raise ConfigError(source, k, f"expected a camera preset name, got {cfg.get(k)!r}")
        cams[k] = cfg[k]
    port_sec = _section(cfg, "port", _PORT_KEYS, source)
    water_sec = _section(cfg, "water", _WATER_KEYS, source)
    light_sec = _section(cfg, "light", _LIGHT_KEYS, source)
    sensor_sec = _section(cfg, "sensor", _SENSOR_KEYS, source)
    port = None if port_sec is None else _port(port_sec, source)
    medium = None if water_sec is None else _water(water_sec, source)
    if medium is not None and (port is None or port.n_water == port.n_air):
        raise ConfigError(source, "water", "a water medium needs a port with n_water (the outside) != n_air")
    light = None if light_sec is None else _light(light_sec, source)
    sensor = None if sensor_sec is None else _sensor(sensor_sec, source)
    return OpticsPreset(name, cams["nominal_camera"], cams["lens_camera"], port,
                        MediumChain(medium=medium, light=light, sensor=sensor))
