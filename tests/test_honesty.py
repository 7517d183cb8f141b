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
