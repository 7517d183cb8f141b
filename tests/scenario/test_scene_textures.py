"""``site.textures`` (in_situ) and ``sim.textures`` (xy_table): any image on a panel face; bad keys are one-line errors
naming the key."""

from pathlib import Path

import numpy as np
import pytest

from bench.errors import ConfigError
from bench.scenario.runner import load_scenario
from bench.scenario.scene_textures import naming_the_key, texture_paths

ROOT = Path(__file__).resolve().parents[2]
INSITU = ROOT / "scenarios" / "ta40_in_situ_manifold.yaml"
XY = ROOT / "scenarios" / "xy_table_webcam.yaml"
PHOTOS = sorted((ROOT / "scenarios" / "data" / "textures").glob("*.[pj][np]g"))


def test_vendored_photographs_have_provenance():
    assert len(PHOTOS) >= 4
    text = (ROOT / "scenarios" / "data" / "textures" / "PROVENANCE.md").read_text()
    for p in PHOTOS:
        assert p.name in text
    for kind in ("industrial", "natural", "low texture", "repetitive"):
        assert kind in text


def test_relative_and_absolute_paths_resolve():
    cfg = load_scenario(INSITU, overrides=["site.textures.backplate=data/textures/natural_gravel.png"])
    assert texture_paths(cfg, "site.textures") == {"backplate": ROOT / "scenarios" / "data/textures/natural_gravel.png"}
    cfg = load_scenario(INSITU, overrides=[f"site.textures.backplate={PHOTOS[0]}"])
    assert texture_paths(cfg, "site.textures")["backplate"] == PHOTOS[0]


@pytest.mark.parametrize("value, words", [("no/such/photo.jpg", "image file not found"),
                                          ("../README.md", "not a readable image file"),
                                          ("42", "expected an image file name")])
def test_bad_files_name_the_key(value, words):
    with pytest.raises(ConfigError) as exc:
        load_scenario(INSITU, overrides=[f"site.textures.backplate={value}"])
    assert "site.textures.backplate" in str(exc.value) and words in str(exc.value)
    assert "\n" not in str(exc.value)


def test_not_a_mapping_names_the_key():
    with pytest.raises(ConfigError, match="site.textures"):
        load_scenario(INSITU, overrides=["site.textures=photo.jpg"])


def test_unknown_face_names_the_key_and_a_known_face_changes_the_texture():
    from bench.sim.scenes.panel import manifold_panel

    cfg = load_scenario(INSITU, overrides=[f"site.textures.nosuchface={PHOTOS[0]}"])
    with pytest.raises(ConfigError) as exc, naming_the_key(cfg, "site.textures"):
        manifold_panel(np.random.default_rng(0), texture_overrides=texture_paths(cfg, "site.textures"))
    assert "site.textures.nosuchface" in str(exc.value) and "backplate" in str(exc.value)
    plain = manifold_panel(np.random.default_rng(0))
    photo = manifold_panel(np.random.default_rng(0), texture_overrides={"backplate": PHOTOS[0]})
    changed = [k for k in plain.files if plain.files[k] != photo.files[k]]
    assert len(changed) == 1 and "backplate" in changed[0]


def test_xy_table_reference_object_textures():
    cfg = load_scenario(XY, overrides=[f"sim.textures.backplate={PHOTOS[1]}"])
    assert texture_paths(cfg, "sim.textures") == {"backplate": PHOTOS[1]}
    with pytest.raises(ConfigError, match="sim.textures.backplate"):
        load_scenario(XY, overrides=["sim.textures.backplate=missing.png"])


def test_xy_table_desk_robot_textures():
    from bench.scenario.xy_table import reference_object

    cfg = load_scenario(XY, overrides=["sim.reference_object=robot", f"sim.textures.wall={PHOTOS[0]}"])
    plain = load_scenario(XY, overrides=["sim.reference_object=robot"])
    a, b = reference_object(cfg, np.random.default_rng(1)), reference_object(plain, np.random.default_rng(1))
    assert [k for k in a.files if a.files[k] != b.files[k]] == ["ref_wall.png"]
    bad = load_scenario(XY, overrides=["sim.reference_object=robot", f"sim.textures.backplate={PHOTOS[0]}"])
    with pytest.raises(ConfigError, match=r"sim.textures.backplate.*wall"):
        reference_object(bad, np.random.default_rng(1))
