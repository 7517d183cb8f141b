"""Housing and medium parts of the simulator's optics presets (issue 3 item 4).

A preset names the camera specifications (:mod:`bench.camera.presets`) and the physical parts in front of and around
the lens:

* ``air_webcam`` - Table 3 webcam, no port, no water; sensor noise only;
* ``underwater_in_air`` - the underwater camera's housing in air (§5.3, Table 9): the glass slab only
  (``n_water = n_air``, it shifts rays laterally), sensor noise;
* ``underwater_in_water`` - the same housing submerged (§5.5, Table 15): flat port into sea water, ``coastal`` water,
  a co-located lamp, sensor noise.

``lens_camera`` is the camera *inside* the housing (used by :class:`bench.sim.flatport.FlatPortStage` as its lens,
its distortion applied in ray space before the port); ``nominal_camera`` is the specification the pipeline is given
(the thesis's calibration of the whole system). For the submerged camera these differ: the thesis's Table 15 focal
length is 662.6 / 510.06 = 1.30 times Table 9's, close to the flat port's paraxial magnification ``n_water / n_air``
= 1.34 - the port makes the difference. The housing geometry of the MCH-3000P is not given in the thesis: the values
below (20 mm lens-to-glass, 12 mm crown glass, a ~1 deg misalignment - the thesis notes the camera "was not aligned
with the glass", §5.3) are plausible choices, stated as such.
"""

from __future__ import annotations

from dataclasses import dataclass

from bench.sim.flatport import FlatPort
from bench.sim.medium import Light, MediumChain, Sensor, water_preset

#: refractive indices: air 1.000, crown glass (BK7-like) ~1.52, sea water ~1.34 (visible band, 20 C, 35 PSU)
N_AIR, N_GLASS, N_SEAWATER = 1.0, 1.52, 1.34
_HOUSING = dict(d0=0.020, t=0.012, n_air=N_AIR, n_glass=N_GLASS, tilt=(0.015, -0.012), decentre=(0.001, -0.0005))


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


def _air_webcam():
    return OpticsPreset("air_webcam", "air_webcam", "air_webcam", None, MediumChain(sensor=Sensor()))


def _underwater_in_air():
    port = FlatPort(n_water=N_AIR, source="optics preset 'underwater_in_air'", **_HOUSING)
    return OpticsPreset("underwater_in_air", "underwater_in_air", "underwater_in_air", port,
                        MediumChain(sensor=Sensor()))


def _underwater_in_water():
    port = FlatPort(n_water=N_SEAWATER, source="optics preset 'underwater_in_water'", **_HOUSING)
    chain = MediumChain(medium=water_preset("coastal"), light=Light(ref_range_m=1.0, beam_exponent=2.0, ambient=0.15),
                        sensor=Sensor())
    return OpticsPreset("underwater_in_water", "underwater_in_water", "underwater_in_air", port, chain)


_PRESETS = {"air_webcam": _air_webcam, "underwater_in_air": _underwater_in_air,
            "underwater_in_water": _underwater_in_water}


def optics_preset_names() -> list[str]:
    """Names of the optics presets, sorted."""
    return sorted(_PRESETS)


def optics_preset(name: str) -> OpticsPreset:
    """The :class:`OpticsPreset` called ``name``; unknown -> one-line ``ValueError`` listing the known ones."""
    if not isinstance(name, str) or name not in _PRESETS:
        raise ValueError(f"optics preset: unknown {name!r} (known: {', '.join(optics_preset_names())})")
    return _PRESETS[name]()
