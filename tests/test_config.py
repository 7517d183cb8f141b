"""The declarative checks of user files (:mod:`bench.config`, pydantic v2 models): every problem is one line naming
the file and the dotted key, never pydantic's multi-line report."""

import importlib
from pathlib import Path

import pytest
import yaml

from bench.config import Section, leaves, parse
from bench.errors import ConfigError
from bench.scenario.runner import KINDS, load_scenario

ROOT = Path(__file__).resolve().parents[1]
TRACKER = ROOT / "scenarios" / "tracker_base_frame.yaml"
IN_SITU = ROOT / "scenarios" / "ta40_in_situ_manifold.yaml"


def _refused(path, override) -> str:
    with pytest.raises(ConfigError) as exc:
        load_scenario(path, overrides=[override])
    msg = str(exc.value)
    assert "\n" not in msg and msg.split(": ", 1)[0].endswith(path.name), msg
    return msg


@pytest.mark.parametrize("override, says", [
    ("noise.colour=red", "noise.colour: unknown key (allowed: default_sigma_mm, sigmas_mm)"),
    ("noise.sigma_mm=0.1", "noise.sigma_mm: unknown key (did you mean 'noise.sigmas_mm'?)"),
    ("colour=red", "colour: unknown key"),
    ("noise.default_sigma_mm=true", "noise.default_sigma_mm: expected float, got bool True"),
    ("noise.default_sigma_mm=.nan", "noise.default_sigma_mm: must be finite, got nan"),
    ("noise.default_sigma_mm=-.inf", "noise.default_sigma_mm: must be finite, got -inf"),
    ("monte_carlo.trials=20.0", "monte_carlo.trials: expected int, got float 20.0"),
    ("monte_carlo.trials=true", "monte_carlo.trials: expected int, got bool True"),
    ("noise.sigmas_mm=[0.1, true]", "noise.sigmas_mm: expected a number, got bool True (item 2 of [0.1, True])"),
    ("noise.sigmas_mm=[0.1, .nan]", "noise.sigmas_mm: must be finite"),
    ("noise=3", "noise: expected a mapping, got int 3"),
    ("noise.default_sigma_mm=-0.05", "noise.default_sigma_mm: must be > 0 mm, got -0.05"),
    ("name=null", "name: expected str, got NoneType None"),
])
def test_bad_values_are_one_line_errors_naming_the_dotted_key(override, says):
    assert says in _refused(TRACKER, override)


@pytest.mark.parametrize("override, says", [
    ("camera.foo.bar=1", "camera.foo: unknown key (allowed: preset, supersample"),
    ("camera.supersampl=2", "camera.supersampl: unknown key (did you mean 'camera.supersample'?)"),
    ("outputs.rerun.x=1", "outputs.rerun: expected bool, got dict {'x': 1}"),
    ("camera.supersample.x=1", "camera.supersample.x: 'supersample' is not a section"),
])
def test_set_of_an_unknown_nested_key(override, says):
    assert says in _refused(IN_SITU, override)


def test_an_int_for_a_float_is_a_float_and_lists_keep_their_numbers():
    cfg = load_scenario(TRACKER, overrides=["noise.default_sigma_mm=1", "arcs.spans_deg=[20, 40.5]"])
    assert cfg["noise"]["default_sigma_mm"] == 1.0 and isinstance(cfg["noise"]["default_sigma_mm"], float)
    assert cfg["arcs"]["spans_deg"] == [20, 40.5] and isinstance(cfg["arcs"]["spans_deg"][0], int)


def test_missing_required_key():
    from bench.scenario.runner import check_scenario

    with pytest.raises(ConfigError, match=r"s.yaml: truth.errors_csv: missing"):
        check_scenario({"name": "x", "kind": "kinematic_identification"}, "s.yaml")


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_section_of_every_kind_forbids_unknown_keys(kind):
    model = importlib.import_module(f"bench.scenario.{kind}").Scenario
    sections = {key.rsplit(".", 1)[0] for key, _ in leaves(model) if "." in key}
    assert sections
    for section in sections:
        raw = {"name": "x", "kind": kind}
        if kind == "kinematic_identification":
            raw["truth"] = {"errors_csv": "t.csv"}
        raw[section] = {**raw.get(section, {}), "no_such_key": 1}
        with pytest.raises(ConfigError, match=rf"^f.yaml: {section}.no_such_key: unknown key \((allowed|did you)"):
            parse(model, raw, "f.yaml")


def test_a_plain_model_error_never_leaks_pydantic_text():
    class M(Section):
        x: int = 1

    with pytest.raises(ConfigError) as exc:
        parse(M, {"x": "1"}, "m.yaml")
    assert str(exc.value) == "m.yaml: x: expected int, got str '1'"


# ------------------------------------------------------------------------------------------------ dataset manifest


def _dataset(tmp_path):
    import numpy as np

    from bench.dataset import DatasetWriter

    with DatasetWriter(tmp_path / "ds", kind="camera_calibration") as w:
        w.add_view("v0", np.zeros((8, 8, 3), np.uint8), role="rig")
        w.add_view("v1", np.zeros((8, 8, 3), np.uint8), role="rig")
    return tmp_path / "ds"


@pytest.mark.parametrize("edit, says", [
    (lambda m: m["views"][1].update(colour="red"), r"views\[1\].colour: unknown key \(allowed: name, image"),
    (lambda m: m["views"][1].update(name="v0"), r"views\[1\].name: duplicate view 'v0'"),
    (lambda m: m["views"][0].update(name=""), r"views\[0\].name: expected a non-empty string, got ''"),
    (lambda m: m["views"][0].pop("name"), r"views\[0\].name: missing"),
    (lambda m: m.update(units={"length": "m", "angle": "deg"}), r"units.length: expected mm, got 'm'"),
    (lambda m: m.update(kind="levitation"), r"kind: expected one of in_situ, camera_calibration, xy_table, kinematic"),
    (lambda m: m.update(format="v2"), r"format: expected insitu-bench-dataset/1, got 'v2'"),
    (lambda m: m.update(views={"v0": 1}), r"views: expected list, got dict"),
])
def test_manifest_problems_are_one_line_errors(tmp_path, edit, says):
    from bench.dataset import load_dataset

    root = _dataset(tmp_path)
    man = yaml.safe_load((root / "manifest.yaml").read_text())
    edit(man)
    (root / "manifest.yaml").write_text(yaml.safe_dump(man))
    with pytest.raises(ConfigError, match=r"manifest.yaml: " + says) as exc:
        load_dataset(root)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("raw, key, says", [
    ({"name": "n", "kind": ["in_situ"]}, "kind", "unknown scenario kind ['in_situ']"),
    ({"name": "n", "kind": {"a": 1}}, "kind", "unknown scenario kind"),
    ({"name": "n"}, "kind", "missing (known kinds:"),
    ({"name": "n", "kind": "in_situ", 1: 2}, "<top>", "unknown key 1"),
    ({"name": "n", "kind": "in_situ", "truth": {True: 2}}, "truth", "unknown key True"),
])
def test_a_kind_or_key_of_the_wrong_type_is_one_line(raw, key, says):
    """A YAML `kind:` that is a list or mapping, a missing kind, and a key that is not a name (`1:`, `true:`): one
    line naming the key, never a TypeError or pydantic's own wording."""
    from bench.scenario.runner import check_scenario

    with pytest.raises(ConfigError) as e:
        check_scenario(raw, "f.yaml")
    text = str(e.value)
    assert f"f.yaml: {key}: " in text and says in text and "\n" not in text, text
