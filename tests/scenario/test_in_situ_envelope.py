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


class _Planned(Exception):
    """Raised by a stand-in renderer: the planning of every view succeeded (nothing is rendered)."""


@pytest.fixture
def plan_only(monkeypatch):
    import bench.sim.campaign as campaign

    def stand_in(*args, **kwargs):
        raise _Planned

    monkeypatch.setattr(campaign, "ArmScene", stand_in)

    def plan(overrides, seed=1):
        cfg = load_scenario(SCENARIO, seed=seed, overrides=["lab.rig_views=3", *overrides])
        with pytest.raises(_Planned):
            IN_SITU.render(cfg, "unused", verbose=False)
    return plan


@pytest.mark.parametrize("standoff", [0.5, 0.7, 1.0, 1.5])
def test_standoffs_of_the_envelope_are_reachable(plan_only, standoff):
    """With the reference eye placed where the arm reaches it (site.placement: eye) every standoff of the envelope
    plans its survey and locate views, also with the base moved 0.5 m / 20 deg between survey and localisation."""
    plan_only(["site.placement=eye", f"site.standoff_m={standoff}", "task.teach=false",
               "survey.radius_limit_mm=200", "locate.motion_m=0.5", "locate.motion_deg=20"], seed=3)


def test_unreachable_views_are_refused_in_numbers(tmp_path):
    cfg = load_scenario(SCENARIO, seed=1, overrides=["lab.rig_views=3", "site.parking_attempts=2",
                                                     "site.placement=eye", "site.eye_m=[2.5, 0.45, 0.85]"])
    with pytest.raises(ConfigError) as exc:
        IN_SITU.render(cfg, tmp_path / "ds", verbose=False)
    msg = str(exc.value)
    assert "wrist centre 2.25 m from the shoulder" in msg and "reaches 1.04-1.52 m" in msg and "723 mm beyond" in msg
    assert not (tmp_path / "ds").exists()


def test_placement_and_radius_limit_are_checked():
    for overrides, key in ((["site.placement=floating"], "site.placement"), (["site.eye_m=[1, 2]"], "site.eye_m"),
                           (["survey.radius_limit_mm=-5"], "survey.radius_limit_mm")):
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            load_scenario(SCENARIO, seed=1, overrides=overrides)
    from bench.camera.presets import load_preset

    cfg = load_scenario(SCENARIO, seed=1, overrides=["site.standoff_m=1.5", "survey.radius_limit_mm=200"])
    r = np.linalg.norm(IN_SITU._survey_offsets(cfg, load_preset("underwater_in_water")), axis=1)
    np.testing.assert_allclose(r, 0.2)
    cfg = load_scenario(SCENARIO, seed=1, overrides=["site.standoff_m=0.5", "survey.radius_limit_mm=200"])
    assert np.all(np.linalg.norm(IN_SITU._survey_offsets(cfg, load_preset("underwater_in_water")), axis=1) < 0.2)


def test_locate_baseline_direction_turns_the_pair_in_the_image_plane():
    """``locate.baseline_direction_deg``: 0 is the thesis's pair across the panel (the exact offsets of before), 90
    puts the second eye above the first (image-up is the look frame's -y), the baseline's length kept."""
    np.testing.assert_array_equal(IN_SITU.locate_offsets(0.3), [[-0.15, 0, 0], [0.15, 0, 0]])
    up = IN_SITU.locate_offsets(0.3, 90.0)
    np.testing.assert_allclose(up, [[0, 0.15, 0], [0, -0.15, 0]], atol=1e-15)
    for a in (-135.0, 30.0, 180.0):
        off = IN_SITU.locate_offsets(0.3, a)
        assert abs(np.linalg.norm(off[1] - off[0]) - 0.3) < 1e-15 and np.all(off[:, 2] == 0)
    with pytest.raises(ConfigError, match=r"locate\.baseline_direction_deg"):
        load_scenario(SCENARIO, seed=1, overrides=["locate.baseline_direction_deg=270"])


def test_a_vertical_locate_pair_is_reachable(plan_only):
    plan_only(["locate.baseline_direction_deg=90"])
