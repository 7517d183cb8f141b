"""The in-situ kind's operating envelope keys (issue 13): the water (``site.water``), the standoff (panel placement
``site.placement``, ``site.eye_m``) and refusals stated in numbers."""

from pathlib import Path

import numpy as np
import pytest

from bench.errors import ConfigError
from bench.scenario.runner import kind_module, load_scenario
from bench.sim.medium import WATER_PRESETS

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "ta40_in_situ_manifold.yaml"
IN_SITU = kind_module("in_situ", SCENARIO)


@pytest.mark.parametrize("water", ["clear_ocean", "coastal", "turbid_harbour"])
def test_site_water_selects_the_preset(water):
    cfg = load_scenario(SCENARIO, seed=1, overrides=[f"site.water={water}"])
    medium = IN_SITU.site_optics(cfg).chain.medium
    assert medium.name == water
    np.testing.assert_array_equal(medium.beta_D_per_m, WATER_PRESETS[water]["beta_D_per_m"])
    np.testing.assert_array_equal(medium.B_inf, WATER_PRESETS[water]["B_inf"])


def test_site_water_preset_keeps_the_camera_presets_own_water():
    cfg = load_scenario(SCENARIO, seed=1)
    assert cfg["site"]["water"] == "preset" and IN_SITU.site_optics(cfg).chain.medium.name == "coastal"
    cfg = load_scenario(SCENARIO, seed=1, overrides=["camera.preset=air_webcam"])
    assert IN_SITU.site_optics(cfg).chain.medium is None


@pytest.mark.parametrize("overrides, says", [
    (["site.water=mud"], "unknown water 'mud'"),
    (["site.water=Coastal"], "unknown water 'Coastal'"),
    (["site.water=turbid_harbour", "camera.preset=air_webcam"], "needs a camera in water"),
    (["site.water=clear_ocean", "camera.preset=underwater_in_air"], "needs a camera in water"),
])
def test_site_water_refuses_in_one_line_naming_the_key(overrides, says):
    with pytest.raises(ConfigError) as exc:
        load_scenario(SCENARIO, seed=1, overrides=overrides)
    msg = str(exc.value)
    assert "site.water" in msg and says in msg and "\n" not in msg
