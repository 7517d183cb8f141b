"""Issue 17.1: no command deletes or replaces what it did not create (bench.fileio's output claims).

For every command that writes: ``--out`` onto a folder holding a user's file, onto a file (where a folder is
expected) or a folder (where a file is expected) is refused in one line and leaves everything as it was; ``--force``
never changes that; a command's own previous output is written again (a sweep resumes), and ``--force`` replaces
it. Files are written with the permissions of a plain ``open()`` (the umask), not ``mkstemp``'s 0600.
"""

import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.fileio import (
    OUTPUT_MARKER,
    OutputRefused,
    atomic_write_text,
    check_output_dir,
    claim_output_dir,
    write_output_file,
)

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "scenarios"
TRACKER = SCEN / "tracker_base_frame.yaml"
TINY = ["--set", "monte_carlo.trials=2", "--set", "arcs.spans_deg=[90]", "--set", "noise.sigmas_mm=[0.05]",
        "--set", "outputs.plots=false", "--set", "arcs.n_points=6"]


def snapshot(folder: Path) -> dict:
    """``{relative path: bytes}`` of everything under ``folder`` (hidden files included)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def places(tmp_path):
    """A user's folder with a note, a user's plain file and a user's folder (for file outputs)."""
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("my notes\n")
    plain = tmp_path / "plain.txt"
    plain.write_text("a user's file\n")
    return {"folder": user, "file": plain, "before": snapshot(tmp_path)}


def refused(capsys, argv, *patterns):
    assert main(argv) == 2, argv
    err = capsys.readouterr().err.strip()
    assert err.startswith("bench: error: ") and err.count("\n") == 0, err
    for p in patterns:
        assert p in err, err
    return err


def assert_untouched(tmp_path, places):
    assert snapshot(tmp_path) == places["before"]


# ------------------------------------------------------------------------------------------------ the mechanism


def test_claim_rules(tmp_path):
    new = claim_output_dir(tmp_path / "a" / "b", "run", identity="s1")
    assert json.loads((new / OUTPUT_MARKER).read_text())["command"] == "run"
    (new / "result.json").write_text("{}")
    assert check_output_dir(new, "run", identity="s1") == "own"
    assert check_output_dir(new, "run", identity="s1", force=True) == "replace"
    with pytest.raises(OutputRefused, match="for 's1', not 's2'; --force replaces it"):
        check_output_dir(new, "run", identity="s2")
    with pytest.raises(OutputRefused, match="holds the output of bench run, not of bench sweep"):
        check_output_dir(new, "sweep", force=True)
    claim_output_dir(new, "run", identity="s2", force=True)
    assert sorted(p.name for p in new.iterdir()) == [OUTPUT_MARKER]  # replaced whole
    empty = tmp_path / "empty"
    empty.mkdir()
    assert check_output_dir(empty, "run") == "empty"
    with pytest.raises(OutputRefused, match="is a file"):
        check_output_dir(new / OUTPUT_MARKER / "x", "run")
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / OUTPUT_MARKER).write_text("not json")  # a damaged marker is not a claim
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(tmp_path / "broken", "run", force=True)


def test_settings_identity_names_what_differs(tmp_path):
    """An output computed from files and settings: the same ones (a relative path to the same file too) write into it
    again; others are refused naming each difference; --force replaces it."""
    from bench.fileio import settings_identity

    (tmp_path / "camera.yaml").write_text("x")
    one = settings_identity({"camera": tmp_path / "camera.yaml", "priors": None}, seed=1, refine="joints")
    out = claim_output_dir(tmp_path / "out", "locate", identity=one)
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)
        again = settings_identity({"camera": "camera.yaml", "priors": None}, refine="joints", seed=1)
    finally:
        os.chdir(cwd)
    assert again == one and check_output_dir(out, "locate", identity=again) == "own"
    other = settings_identity({"camera": tmp_path / "camera.yaml", "priors": tmp_path / "p.yaml"}, seed=2,
                              refine="joints")
    with pytest.raises(OutputRefused, match=r"with other settings: priors not given \(this call: .*p\.yaml\), "
                                            r"seed 1 \(this call: 2\); --force replaces it"):
        check_output_dir(out, "locate", identity=other)
    assert check_output_dir(out, "locate", identity=other, force=True) == "replace"


def test_a_claim_killed_before_its_marker_landed_is_claimed_again(tmp_path):
    """SIGKILL between the folder's creation and the marker's rename leaves only the marker's temporary file: the
    resumed command (a sweep's run) claims the folder again instead of refusing it as foreign, forever."""
    run = tmp_path / "runs" / "abc"
    run.mkdir(parents=True)
    (run / f".{OUTPUT_MARKER}.k2j4x.tmp").write_text("")
    assert check_output_dir(run, "run", identity="s1") == "empty"
    claim_output_dir(run, "run", identity="s1")
    assert json.loads((run / OUTPUT_MARKER).read_text())["identity"] == "s1"
    (run / "notes.txt").write_text("mine")  # anything else still makes it foreign
    (run / OUTPUT_MARKER).unlink()
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(run, "run", identity="s1")


def test_outputs_of_older_versions_are_adopted_by_their_signature(tmp_path):
    """Folders written before markers existed: a sweep (its store), a run of the same scenario (its result.json)."""
    import sqlite3

    sweep = tmp_path / "sweep"
    sweep.mkdir()
    sqlite3.connect(sweep / "sweep.sqlite").execute("CREATE TABLE runs (run_id TEXT)").connection.close()
    assert check_output_dir(sweep, "sweep") == "own"
    claim_output_dir(sweep, "sweep", identity="s.yaml")
    assert json.loads((sweep / OUTPUT_MARKER).read_text())["command"] == "sweep"
    run = tmp_path / "run"
    run.mkdir()
    (run / "result.json").write_text(json.dumps({"scenario": "s1", "metrics": {}}))
    assert check_output_dir(run, "run", identity="s1") == "own"
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(run, "run", identity="s2")  # another scenario's result: not adopted
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(run, "sweep")
    other = tmp_path / "other"
    other.mkdir()
    sqlite3.connect(other / "sweep.sqlite").execute("CREATE TABLE notes (x TEXT)").connection.close()
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(other, "sweep")
    # a budget: its result.json with the variants' stores it names; a copy of the result files alone is not one
    budget = tmp_path / "budget"
    (budget / "full").mkdir(parents=True)
    sqlite3.connect(budget / "full" / "sweep.sqlite").execute("CREATE TABLE runs (run_id TEXT)").connection.close()
    result = {"scenario": "budget:s", "metrics": {}, "artifacts": {"budget": "budget.csv",
                                                                    "sweep_full": "full/sweep.sqlite"}}
    (budget / "result.json").write_text(json.dumps(result))
    (budget / "budget.csv").write_text("source\n")
    assert check_output_dir(budget, "budget", identity="s.yaml") == "own"
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(budget, "budget", identity="t.yaml")  # another scenario's budget: not adopted
    copy = tmp_path / "copy"  # found by misuse: the result files copied by hand were adopted and written over
    copy.mkdir()
    (copy / "result.json").write_text(json.dumps(result))
    (copy / "budget.csv").write_text("source\n")
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(copy, "budget", identity="s.yaml")
    (run / "result.json").write_text(json.dumps({"scenario": "s1", "metrics": {}, "artifacts": {"dataset": "dataset"}}))
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(run, "run", identity="s1")  # a run's result.json without the dataset it names
    (run / "dataset").mkdir()
    assert check_output_dir(run, "run", identity="s1") == "own"


def test_unmarked_locate_and_calibration_folders_are_adopted_only_whole(tmp_path):
    """Found by misuse: a folder holding any locate.json (one's notes beside a copied report) was adopted by
    ``bench locate --out`` and its report written over. Adopted: a report with the command's keys, for the same
    dataset, in a folder holding nothing the command does not write."""
    from bench.fileio import settings_identity

    data = tmp_path / "dataset"
    data.mkdir()
    ident = settings_identity({"dataset": data, "camera": None, "robot": None, "priors": None}, seed=0)
    report = {"dataset": str(data), "success": True, "map_points": 3, "timings_s": {}}
    out = tmp_path / "loc"
    out.mkdir()
    (out / "locate.json").write_text(json.dumps(report))
    assert check_output_dir(out, "locate", identity=ident) == "own"
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(out, "locate", identity=ident)
    (out / "notes.txt").unlink()
    (out / "locate.json").write_text(json.dumps({"my": "summary"}))  # a file of one's own by that name
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(out, "locate", identity=ident)
    (out / "locate.json").write_text(json.dumps({**report, "dataset": str(tmp_path / "elsewhere")}))
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(out, "locate", identity=ident)  # another dataset's report
    cal = tmp_path / "cal"
    cal.mkdir()
    (cal / "calibration.json").write_text(json.dumps({"dataset": str(data), "views_used": [], "success": True,
                                                       "reproj_rms_px": 0.1, "timings_s": {}}))
    (cal / "camera.yaml").write_text("%YAML:1.0\n")
    cal_ident = settings_identity({"dataset": data, "robot": None}, model="eq50")
    assert check_output_dir(cal, "calibrate-camera", identity=cal_ident) == "own"
    (cal / "paper.pdf").write_text("mine")
    with pytest.raises(OutputRefused, match="bench did not write"):
        check_output_dir(cal, "calibrate-camera", identity=cal_ident)


def test_output_files_are_claimed_by_content(tmp_path):
    out = tmp_path / "robot.urdf"
    write_output_file(out, "<robot/>", "export")
    write_output_file(out, "<robot name='b'/>", "export")  # its own, unchanged since: replaced
    out.write_text("<robot/> <!-- edited by hand -->")
    with pytest.raises(OutputRefused, match="changed since bench export wrote it; --force replaces it"):
        write_output_file(out, "<robot/>", "export")
    write_output_file(out, "<robot/>", "export", force=True)
    with pytest.raises(OutputRefused, match="written by bench export, not by bench export-camera"):
        write_output_file(out, "x", "export-camera", force=True)
    assert out.read_text() == "<robot/>"


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_files_and_dataset_folders_honour_the_umask(tmp_path, umask):
    from bench.dataset import DatasetWriter

    old = os.umask(umask)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        with DatasetWriter(tmp_path / "ds", kind="in_situ") as w:
            w.add_view("v0", np.zeros((4, 4, 3), np.uint8), q=np.zeros(6))
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o666 & ~umask
    assert stat.S_IMODE((tmp_path / "ds").stat().st_mode) == 0o777 & ~umask
    assert stat.S_IMODE((tmp_path / "ds" / "manifest.yaml").stat().st_mode) == 0o666 & ~umask


# ------------------------------------------------------------------------------------------------ folder commands


def test_run(tmp_path, places, capsys):
    base = ["run", str(TRACKER), *TINY, "--quiet"]
    refused(capsys, base + ["--out", str(places["folder"])], "bench did not write", "notes.txt")
    refused(capsys, base + ["--out", str(places["folder"]), "--force"], "--force only replaces")
    refused(capsys, base + ["--out", str(places["file"])], "is a file, not a folder")
    assert_untouched(tmp_path, places)
    out = tmp_path / "r"
    assert main(base + ["--out", str(out)]) == 0
    first = json.loads((out / "result.json").read_text())
    assert main(base + ["--out", str(out)]) == 0  # its own output: re-run in place
    again = json.loads((out / "result.json").read_text())["metrics"]
    assert {k: v for k, v in again.items() if not k.endswith("_s")} == \
        {k: v for k, v in first["metrics"].items() if not k.endswith("_s")}
    (out / "stale.csv").write_text("x")  # a user's file in the run's folder: kept when the run re-runs ...
    assert main(base + ["--out", str(out)]) == 0 and (out / "stale.csv").read_text() == "x"
    refused(capsys, base + ["--out", str(out), "--force"], "holds 'stale.csv', which bench did not write there")
    assert (out / "stale.csv").read_text() == "x"  # ... and --force does not delete it
    (out / "stale.csv").unlink()
    (out / "base_accuracy_vs_noise.csv").write_text("edited")
    assert main(base + ["--out", str(out), "--force"]) == 0  # --force: a fresh run over the run's own files
    assert (out / "base_accuracy_vs_noise.csv").read_text() != "edited"
    refused(capsys, ["sweep", str(TRACKER), "--out", str(out)], "holds the output of bench run, not of bench sweep")
    capsys.readouterr()


def test_a_run_with_another_seed_or_override_does_not_take_the_place_of_the_last(tmp_path, capsys):
    """``bench run --out X --seed 2`` over a seed-1 run of the same scenario was written in place, losing the first
    result without a word; now refused by name (the seed, the overrides), and ``--force`` replaces it."""
    base = ["run", str(TRACKER), *TINY, "--quiet"]
    out = tmp_path / "r"
    assert main(base + ["--out", str(out), "--seed", "1"]) == 0
    first = (out / "result.json").read_text()
    refused(capsys, base + ["--out", str(out), "--seed", "2"], "with other settings: seed 1 (this call: 2); "
            "--force replaces it")
    err = refused(capsys, base + ["--out", str(out), "--seed", "1", "--set", "arcs.n_points=7"],
                  "with other settings: set [")
    assert "'arcs.n_points=7'] (this call" not in err and "'arcs.n_points=7']); --force" in err
    assert (out / "result.json").read_text() == first
    assert main(base + ["--out", str(out), "--seed", "1"]) == 0  # the same settings: re-run in place
    assert main(base + ["--out", str(out), "--seed", "2", "--force"]) == 0
    assert json.loads((out / "result.json").read_text())["seed"] == 2
    capsys.readouterr()


def test_a_run_marked_by_an_older_version_is_compared_by_its_seed(tmp_path):
    """Older versions recorded a run's identity as the scenario's name alone: a call with that scenario and the
    seed of the folder's result.json re-runs it in place; another seed is refused naming both."""
    from bench.scenario.runner import load_scenario, run_identity

    run = tmp_path / "old"
    run.mkdir()
    (run / "result.json").write_text(json.dumps({"scenario": "s1", "seed": 3, "metrics": {}}))
    (run / OUTPUT_MARKER).write_text(json.dumps({"command": "run", "identity": "s1"}))
    cfg = {**load_scenario(TRACKER), "name": "s1"}
    assert check_output_dir(run, "run", identity=run_identity({**cfg, "seed": 3})) == "own"
    with pytest.raises(OutputRefused, match=r"seed 3 \(this call: 4\)"):
        check_output_dir(run, "run", identity=run_identity({**cfg, "seed": 4}))
    (run / OUTPUT_MARKER).unlink()  # written before markers: adopted by its result.json the same way
    assert check_output_dir(run, "run", identity=run_identity({**cfg, "seed": 3})) == "own"
    with pytest.raises(OutputRefused, match=r"seed 3 \(this call: 4\)"):
        check_output_dir(run, "run", identity=run_identity({**cfg, "seed": 4}))


def test_sweep(tmp_path, places, capsys):
    base = ["sweep", str(TRACKER), *TINY, "--workers", "1"]
    refused(capsys, base + ["--out", str(places["folder"])], "bench did not write")
    refused(capsys, base + ["--out", str(places["folder"]), "--force"], "bench did not write")
    refused(capsys, base + ["--out", str(places["file"])], "is a file")
    assert_untouched(tmp_path, places)
    out = tmp_path / "sw"
    assert main(base + ["--out", str(out)]) == 0
    rows = (out / "sweep.sqlite").stat().st_size
    assert main(base + ["--out", str(out), "--seeds", "2"]) == 0  # resumed: seed 0 kept, seed 1 added
    assert "2 finished runs" in capsys.readouterr().out
    assert (out / "sweep.sqlite").stat().st_size >= rows
    assert main(base + ["--out", str(out), "--force"]) == 0  # afresh: one run again
    assert "1 finished runs" in capsys.readouterr().out
    (out / "notes.txt").write_text("mine")
    assert main(base + ["--out", str(out), "--seeds", "2"]) == 0  # resumes around the user's file
    capsys.readouterr()
    refused(capsys, base + ["--out", str(out), "--force"], "holds 'notes.txt', which bench did not write there")
    assert (out / "notes.txt").read_text() == "mine"


def test_budget_refuses_before_any_run(tmp_path, places, capsys):
    base = ["budget", str(SCEN / "ta40_in_situ_manifold.yaml"), "--seeds", "1"]
    refused(capsys, base + ["--out", str(places["folder"])], "bench did not write")
    refused(capsys, base + ["--out", str(places["folder"]), "--force"], "bench did not write")
    refused(capsys, base + ["--out", str(places["file"])], "is a file")
    assert_untouched(tmp_path, places)


def test_sim_render_refuses_before_rendering(tmp_path, places, capsys, monkeypatch):
    import bench.scenario.xy_table as kind

    monkeypatch.setattr(kind, "render", lambda *a, **k: pytest.fail("rendered before the refusal"))
    base = ["sim", "render", str(SCEN / "xy_table_webcam.yaml")]
    refused(capsys, base + ["--out", str(places["folder"])], "bench did not write", "notes.txt")
    refused(capsys, base + ["--out", str(places["folder"]), "--force"], "bench did not write")
    refused(capsys, base + ["--out", str(places["file"])], "is a file")
    assert_untouched(tmp_path, places)
    assert not (tmp_path / ".render_cache").exists()


def test_sim_render_replaces_only_its_own_dataset(tmp_path, capsys, monkeypatch):
    """The write path of ``sim render`` (a DatasetWriter in a claimed folder), with a stand-in for the renderer."""
    import bench.scenario.in_situ as kind
    from bench.dataset import DatasetWriter, load_dataset

    def fake_render(cfg, out, verbose=True, cache_dir=None):
        with DatasetWriter(out, kind="in_situ", name=cfg["name"], overwrite=True, command="sim render",
                           identity=cfg["name"]) as w:
            w.add_view(f"seed{cfg['seed']}", np.zeros((4, 4, 3), np.uint8), q=np.zeros(6), role="reference")
        return {"views_rendered": 1.0}

    monkeypatch.setattr(kind, "render", fake_render)
    base = ["sim", "render", str(SCEN / "ta40_in_situ_manifold.yaml"), "--out", str(tmp_path / "ds")]
    assert main(base + ["--seed", "1"]) == 0
    assert main(base + ["--seed", "2"]) == 0  # its own dataset: replaced whole
    assert [v.name for v in load_dataset(tmp_path / "ds").views] == ["seed2"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]  # no temporary or old folder left
    (tmp_path / "ds" / "my_notes.txt").write_text("mine")  # the user's, inside the dataset: never replaced
    monkeypatch.setattr(kind, "render", lambda *a, **k: pytest.fail("rendered before the refusal"))
    for extra in ([], ["--force"]):
        refused(capsys, base + ["--seed", "3", *extra], "holds 'my_notes.txt', which bench did not write there")
    assert (tmp_path / "ds" / "my_notes.txt").read_text() == "mine"
    assert [v.name for v in load_dataset(tmp_path / "ds").views] == ["seed2"]
    (tmp_path / "ds" / "my_notes.txt").unlink()
    refused(capsys, ["sim", "render", str(SCEN / "xy_table_webcam.yaml"), "--out", str(tmp_path / "ds")],
            "for 'ta40_in_situ_manifold', not 'xy_table_webcam'; --force replaces it")
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    with pytest.raises(OutputRefused, match="bench did not write"):
        DatasetWriter(tmp_path / "foreign", kind="in_situ", overwrite=True, force=True)


@pytest.fixture(scope="module")
def planar(tmp_path_factory, ta40):
    from bench.geometry.transforms import homogeneous, rot_z
    from tests.vision.planar_scene import write_planar_dataset

    root = tmp_path_factory.mktemp("planar") / "ds"
    write_planar_dataset(root, ta40, homogeneous(rot_z(np.deg2rad(4.0)), [0.08, -0.05, 0.02]), seed=7)
    return root


def test_locate(tmp_path, places, planar, capsys):
    base = ["locate", str(planar)]
    refused(capsys, base + ["--out", str(places["folder"])], "bench did not write")
    refused(capsys, base + ["--out", str(places["folder"]), "--force"], "bench did not write")
    refused(capsys, base + ["--out", str(places["file"])], "is a file")
    assert_untouched(tmp_path, places)
    out = tmp_path / "loc"
    assert main(base + ["--out", str(out)]) == 0
    assert main(base + ["--out", str(out)]) == 0  # its own output
    assert main(base + ["--out", str(out), "--force"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [OUTPUT_MARKER, "locate.json"]
    (out / "notes.txt").write_text("mine")
    assert main(base + ["--out", str(out)]) == 0
    refused(capsys, base + ["--out", str(out), "--force"], "holds 'notes.txt'")
    assert (out / "notes.txt").read_text() == "mine"
    refused(capsys, ["calibrate-camera", str(planar), "--out", str(out)], "holds the output of bench locate")
    (out / "notes.txt").unlink()
    before = snapshot(out)  # another seed would overwrite a localisation made with other settings: refused
    refused(capsys, base + ["--out", str(out), "--seed", "4"], "with other settings: seed 0 (this call: 4)")
    assert snapshot(out) == before
    assert main(base + ["--out", str(out), "--seed", "4", "--force"]) == 0


def test_calibrate_camera(tmp_path, places, planar, capsys):
    base = ["calibrate-camera", str(planar)]
    refused(capsys, base + ["--out", str(places["folder"])], "bench did not write")
    refused(capsys, base + ["--out", str(places["folder"]), "--force"], "bench did not write")
    refused(capsys, base + ["--out", str(places["file"])], "is a file")
    assert_untouched(tmp_path, places)


# ------------------------------------------------------------------------------------------------ file commands


def _inputs(tmp_path, ta40):
    from bench.camera.io import write_camera_yaml
    from bench.camera.presets import load_preset, preset_names
    from bench.robot.calibration_file import write_calibrated_robot
    from bench.robot.model import default_robot_path

    inp = tmp_path / "inputs"
    robot = write_calibrated_robot(inp / "robot.yaml", default_robot_path(), ta40, np.zeros(42), np.eye(4))
    camera = write_camera_yaml(inp / "camera.yaml", load_preset(preset_names()[0]))
    q = np.random.default_rng(17).uniform(-1, 1, (3, 6))
    header = "point,x_mm,y_mm,z_mm," + ",".join(f"q{i}_deg" for i in range(1, 7))
    tracker = inp / "t.csv"
    tracker.write_text(header + "\n" + "".join(f"P{i},{1000 + i},{20 * i},{300 + i}," + ",".join(map(str, r)) + "\n"
                                               for i, r in enumerate(np.rad2deg(q))))
    joints = inp / "j.csv"
    joints.write_text("view," + ",".join(f"q{i}_deg" for i in range(1, 7)) + "\n"
                      + "".join(f"v{i}," + ",".join(map(str, r)) + "\n" for i, r in enumerate(np.rad2deg(q))))
    return {"export": [str(robot), "--format", "urdf", "--velocity-deg-s", "30", "--effort-nm", "2000"],
            "export-camera": [str(camera), "--format", "ros"],
            "import-tracker": [str(tracker)], "import-joints": [str(joints)]}


@pytest.mark.parametrize("command", ["export", "export-camera", "import-tracker", "import-joints"])
def test_file_commands(tmp_path, places, capsys, ta40, command):
    args = [command, *_inputs(tmp_path, ta40)[command]]
    places["before"] = snapshot(tmp_path)
    refused(capsys, args + ["--out", str(places["file"])], "was written by someone else", "plain.txt")
    refused(capsys, args + ["--out", str(places["file"]), "--force"], "was written by someone else")
    refused(capsys, args + ["--out", str(places["folder"])], "is a folder")
    refused(capsys, args + ["--out", str(places["file"] / "x.out")], "is a file, not a folder")
    assert_untouched(tmp_path, places)
    out = tmp_path / "out" / "file.out"
    assert main(args + ["--out", str(out)]) == 0
    first = out.read_bytes()
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~_umask()
    assert main(args + ["--out", str(out)]) == 0 and out.read_bytes() == first  # its own: written again
    out.write_bytes(first + b"\n# my edit\n")
    refused(capsys, args + ["--out", str(out)], "changed since", "--force replaces it")
    assert main(args + ["--out", str(out), "--force"]) == 0 and out.read_bytes() == first
    other = "import-joints" if command != "import-joints" else "import-tracker"
    refused(capsys, [other, *_inputs(tmp_path, ta40)[other], "--out", str(out), "--force"],
            f"written by bench {command}, not by bench {other}")


def _umask():
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def test_a_sweep_folder_named_with_uri_characters_is_read(tmp_path):
    """Found in review: the read-only SQLite URI was built from the raw path, so a sweep in ``runs/s#2`` read as the
    URI fragment ``#2`` ("no such table: runs"): its rows were not read and it was not recognised as a sweep."""
    import sqlite3

    from bench.scenario.sweep import read_runs

    for name in ("s#2", "a?b", "100%"):
        folder = tmp_path / name
        folder.mkdir()
        con = sqlite3.connect(folder / "sweep.sqlite")
        con.execute("CREATE TABLE runs (run_id TEXT, params TEXT, seed INTEGER, status TEXT, message TEXT, "
                    "metrics TEXT, timings TEXT, result_path TEXT)")
        con.execute("INSERT INTO runs VALUES ('r1', '{}', 3, 'done', '', '{\"x\": 1.0}', '{}', 'r1/result.json')")
        con.commit()
        con.close()
        assert [(r["run_id"], r["seed"], r["metrics"]) for r in read_runs(folder)] == [("r1", 3, {"x": 1.0})]
        assert check_output_dir(folder, "sweep") == "own"
