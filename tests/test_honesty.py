"""Honesty guards: the pipeline never sees the simulator or the truth."""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = ["bench/geometry", "bench/robot", "bench/camera", "bench/vision", "bench/dataset.py", "bench/fileio.py"]
FORBIDDEN = ("mujoco", "bench.sim", "bench.scenario", "bench.judge", "pinocchio")


def _modules():
    for entry in PIPELINE:
        p = ROOT / entry
        yield from ([p] if p.is_file() else sorted(p.rglob("*.py")))


def test_pipeline_sources_import_no_simulator_and_name_no_truth():
    offences = []
    for path in _modules():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            offences += [f"{path.relative_to(ROOT)}: imports {n}" for n in names
                         if any(n == f or n.startswith(f + ".") for f in FORBIDDEN)]
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and "truth/" in node.value \
                    and path.name != "dataset.py":
                offences.append(f"{path.relative_to(ROOT)}: names 'truth/' in {node.value!r}")
    assert not offences, "\n".join(offences)


def test_importing_the_pipeline_loads_no_simulator():
    mods = [".".join(p.relative_to(ROOT).with_suffix("").parts) for p in _modules() if p.name != "__init__.py"]
    code = ("import sys\n" + "".join(f"import {m}\n" for m in mods) +
            "bad = [m for m in sys.modules if m.split('.')[0] in ('mujoco', 'pinocchio') or "
            "m.startswith(('bench.sim', 'bench.scenario', 'bench.judge'))]\nprint(','.join(bad))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"pipeline imports loaded: {r.stdout.strip()}"


def test_the_dataset_reader_never_opens_truth(tmp_path, monkeypatch):
    import numpy as np

    from bench.dataset import DatasetWriter, load_dataset

    with DatasetWriter(tmp_path / "ds", kind="in_situ") as w:
        w.add_view("v", np.zeros((4, 4, 3), np.uint8), q=np.zeros(6))
        w.write_text("truth/truth.yaml", "secret: 1\n")
    opened = []
    real_open = Path.open

    def spy(self, *a, **k):
        opened.append(str(self))
        return real_open(self, *a, **k)

    monkeypatch.setattr(Path, "open", spy)
    load_dataset(tmp_path / "ds").view("v").image()
    assert not [p for p in opened if "truth" in p]


def _base_error(T_est, T_true):
    import numpy as np

    from bench.geometry.transforms import rotation_angle

    return (float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])),
            float(np.rad2deg(rotation_angle(T_est[:3, :3].T @ T_true[:3, :3]))))


def test_locate_follows_the_true_base_motion_and_ignores_the_truth_folder(tmp_path, ta40):
    """Two campaigns whose true base motions differ (4 deg about z and 96 mm, against -3 deg about z, 2 deg about x
    and 79 mm): ``bench locate``'s answers follow each truth to the noise level, differ by the truths' difference,
    and are far from the nominal answer (a base that did not move). Then only ``truth/`` is swapped between the
    datasets: the answers must not change by a single bit."""
    import shutil

    import numpy as np

    from bench.geometry.transforms import homogeneous, invert, rot_x, rot_z
    from bench.vision.locate_dataset import locate_dataset
    from tests.vision.planar_scene import write_planar_dataset

    motions = {"a": homogeneous(rot_z(np.deg2rad(4.0)), [0.08, -0.05, 0.02]),
               "b": homogeneous(rot_z(np.deg2rad(-3.0)) @ rot_x(np.deg2rad(2.0)), [-0.04, 0.06, 0.03])}
    est = {}
    for k, T in motions.items():
        write_planar_dataset(tmp_path / k, ta40, T, seed=11)
        res, _ = locate_dataset(tmp_path / k, verbose=False)
        assert res.success, res.message
        est[k] = res.T_world_base
        pos, rot = _base_error(est[k], T)
        assert pos < 5e-3 and rot < 0.3, (k, pos, rot)  # follows its own truth
        pos0, rot0 = _base_error(est[k], np.eye(4))
        assert pos0 > 10 * 5e-3 and rot0 > 10 * 0.3  # not the nominal (unmoved) base
    pos, rot = _base_error(invert(est["a"]) @ est["b"], invert(motions["a"]) @ motions["b"])
    assert pos < 8e-3 and rot < 0.5  # the answers differ by the truths' difference
    shutil.rmtree(tmp_path / "a" / "truth")
    shutil.copytree(tmp_path / "b" / "truth", tmp_path / "a" / "truth")
    again, _ = locate_dataset(tmp_path / "a", verbose=False)
    assert np.array_equal(again.T_world_base, est["a"])


def test_identification_follows_the_true_errors(tmp_path, ta40):
    """Tracker campaigns of two arms with different true generalized errors, through the dataset files
    (``tracker.csv``, mm and degrees) and the identification: each calibrated model predicts held-out points of its
    own arm to the noise level and misses the other arm's by millimetres, its reduced errors match those of its own
    truth (the noise-free identification of the same arm) within their standard deviations and differ from the other
    estimate by the truths' difference, and neither is the nominal model."""
    import numpy as np

    from bench.dataset import DatasetWriter, load_dataset
    from bench.robot.identifiability import closed_form_reduction
    from bench.robot.identification import identify_iterative
    from bench.robot.kinematics import ee_position
    from bench.robot.model import random_errors

    red = closed_form_reduction(ta40)
    sigma = 5e-5
    rng = np.random.default_rng(12)
    q, q_ho = ta40.random_configurations(rng, 60), ta40.random_configurations(rng, 300)
    eps_true, est, ref = {}, {}, {}

    def rms_mm(a, b):
        return 1e3 * float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))

    for k in ("a", "b"):
        eps_true[k] = random_errors(rng)
        with DatasetWriter(tmp_path / k, kind="kinematic") as w:
            w.write_tracker([f"p{i:03d}" for i in range(len(q))],
                            ee_position(ta40, q, eps_true[k]) + rng.normal(scale=sigma, size=(len(q), 3)), q)
        ds = load_dataset(tmp_path / k)
        res = identify_iterative(ta40, ds.tracker["q"], ds.tracker["p"], red, sigma=sigma)
        assert res.success and "WARNING" not in res.message, res.message
        est[k] = res
        ref[k] = identify_iterative(ta40, q, ee_position(ta40, q, eps_true[k]), red, sigma=sigma).eps_dot
        z = (res.eps_dot - ref[k]) / res.std
        assert np.abs(z).max() < 5 and np.mean(z**2) < 2.5, k
        assert rms_mm(ee_position(ta40, q_ho, res.eps), ee_position(ta40, q_ho, eps_true[k])) < 0.05
        assert rms_mm(ee_position(ta40, q_ho, res.eps), ee_position(ta40, q_ho)) > 1.0  # not the nominal arm
    for k, other in (("a", "b"), ("b", "a")):  # each estimate misses the other arm
        assert rms_mm(ee_position(ta40, q_ho, est[k].eps), ee_position(ta40, q_ho, eps_true[other])) > 1.0
    diff = (est["b"].eps_dot - est["a"].eps_dot) - (ref["b"] - ref["a"])
    assert np.abs(diff / np.hypot(est["a"].std, est["b"].std)).max() < 5
