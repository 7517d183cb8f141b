"""``bench sim export-raw DATASET --out RAW``: a simulated campaign written as real equipment writes it, truth dropped.

The tutorial (``docs/tutorial_real_data.md``) starts from raw files, as a user with a real robot would: this turns a
rendered in-situ dataset (``bench sim render``) into

* ``photos/NAME.jpg`` - the camera's JPEG files (quality ``jpeg_quality``), one per view;
* ``robot_log.csv`` - the controller's joint log: ``;``-separated, a ``frame`` column with the photo's file name
  (or the taught frame's name), readings in degrees in columns ``A1 [deg] .. A6 [deg]``;
* ``tracker_export.txt`` - the laser tracker's point export: tab-separated, ``Point ID``, ``X [m]``, ``Y [m]``,
  ``Z [m]`` and an ``RMS [mm]`` column the bench does not use, in metres;
* ``tracker_robot_log.csv`` - the controller's log of the tracker postures (``;``, ``point``, ``A1 [deg]`` ...);
* ``nominal/robot.yaml``, ``nominal/camera.yaml`` - the nominal files the campaign used;
* ``README.txt`` - which view is which (the roles the tutorial gives ``bench dataset init``).

``truth/`` is not copied: what is left is what a real campaign has.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from bench.dataset import load_dataset
from bench.errors import BenchError, ConfigError


def _csv(rows, sep: str) -> str:
    return "\n".join(sep.join(str(c) for c in r) for r in rows) + "\n"


def export_raw(dataset, out, jpeg_quality: int = 95) -> dict:
    """Write the raw files of a rendered dataset (module docstring) into the new folder ``out``.

    Returns ``{"photos": n, "frames": n, "tracker_points": n, "out": Path}``.
    """
    if not (isinstance(jpeg_quality, int) and 1 <= jpeg_quality <= 100):
        raise BenchError(f"--jpeg-quality: expected an integer in 1..100, got {jpeg_quality!r}")
    out = Path(out)
    if out.exists() and not (out.is_dir() and not any(out.iterdir())):
        raise BenchError(f"--out {out}: exists and is not an empty folder; raw files go into a new folder")
    ds = load_dataset(dataset)
    if ds.robot_path is None or ds.camera_path is None:
        raise ConfigError(ds.root / "manifest.yaml", "robot/camera", "the dataset has no nominal robot or camera file")
    (out / "photos").mkdir(parents=True, exist_ok=True)
    (out / "nominal").mkdir(exist_ok=True)
    log = [["frame", *(f"A{i} [deg]" for i in range(1, 7))]]
    roles = {}
    n_photos = 0
    for v in ds.views:
        key = v.name
        if v.image_path is not None:
            img = v.image()
            bgr = cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img
            key = f"{v.name}.jpg"
            ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
            if not ok:
                raise BenchError(f"{v.image_path}: could not encode as JPEG")
            (out / "photos" / key).write_bytes(buf.tobytes())
            n_photos += 1
        if v.q is not None:
            log.append([key, *(f"{x:.4f}" for x in np.rad2deg(v.q))])
        roles.setdefault(v.role or "(none)", []).append(v.name)
    (out / "robot_log.csv").write_text(_csv(log, ";"))
    n_tr = 0
    if ds.tracker is not None:
        t = ds.tracker
        rng = np.random.default_rng(0)  # the RMS column: a figure trackers print, not read by the bench
        pts = [["Point ID", "X [m]", "Y [m]", "Z [m]", "RMS [mm]"]]
        pts += [[n, *(f"{x:.7f}" for x in p), f"{rng.uniform(0.01, 0.03):.3f}"]
                for n, p in zip(t["point"], t["p"], strict=True)]
        (out / "tracker_export.txt").write_text(_csv(pts, "\t"))
        qlog = [["point", *(f"A{i} [deg]" for i in range(1, 7))]]
        qlog += [[n, *(f"{x:.4f}" for x in np.rad2deg(q))] for n, q in zip(t["point"], t["q"], strict=True)]
        (out / "tracker_robot_log.csv").write_text(_csv(qlog, ";"))
        n_tr = len(t["point"])
    shutil.copyfile(ds.robot_path, out / "nominal" / "robot.yaml")
    shutil.copyfile(ds.camera_path, out / "nominal" / "camera.yaml")
    if (ds.root / "target.yaml").is_file():
        shutil.copyfile(ds.root / "target.yaml", out / "nominal" / "target.yaml")
    lines = [f"Raw files of {ds.name}, exported by bench sim export-raw (no truth).", "Views by role:"]
    lines += [f"  {r}: {', '.join(names)}" for r, names in roles.items()]
    (out / "README.txt").write_text("\n".join(lines) + "\n")
    return {"photos": n_photos, "frames": len(log) - 1, "tracker_points": n_tr, "out": out}
