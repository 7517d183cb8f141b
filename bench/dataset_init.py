"""``bench dataset init``: a dataset folder (:mod:`bench.dataset`) built from the raw files of a campaign.

What a real campaign leaves behind, and what this turns it into:

* a folder of photos (JPEG or PNG; a view is named by its file's stem, ``rig03.jpg`` -> view ``rig03``), copied
  byte for byte into ``images/`` (never re-encoded);
* a joint log (:func:`bench.robot.importers.import_joints` reads it: any delimiter, a key column naming the view,
  ``q1 .. q6``, the unit in the column names, a ``# units: deg`` line or ``--joint-units``) -> ``joints.csv``;
* a laser-tracker export (:func:`bench.robot.importers.import_tracker`: its own column names and units, the joint
  readings as columns or from a second log) -> ``tracker.csv``;
* the nominal robot and camera files -> ``robot.yaml``, ``camera.yaml`` (checked by their readers);
* the calibration target from flags (``--target chessboard --inner 9x6 --square-mm 25``) -> ``target.yaml``.

The views' **roles** come from ``--role ROLE=PATTERN`` (repeatable; shell-style patterns on the view name, e.g.
``--role rig='rig*' --role reference=ref --role surround='survey*' --role locate='locate*' --role task='task_*'``):
``rig`` (calibration target views), ``reference`` / ``surround`` (the survey), ``locate`` (after the base moved) and
``task`` (a frame of joint readings without a photo, e.g. a taught tool pose). With any ``--role`` every photo must
match exactly one pattern. A survey over several parts of the scene names each posed view's **region** the same
way, ``--region NAME=PATTERN`` (e.g. ``--region left='left_*' --region right='right_*'``): with any ``--region``
every reference, surrounding and locate view must match exactly one.

Everything is checked before the dataset is written (atomically: :class:`bench.dataset.DatasetWriter`), each
refusal one line naming the file, line or view: a joint-log row whose photo is missing, a photo without its row in
an in-situ campaign, photos of different sizes or of another size than the camera file, readings outside the robot's
joint limits, a unit not stated, a photo matching no role. A ``--out`` that exists and is not an empty folder is
refused (a dataset is never written over).
"""

from __future__ import annotations

import fnmatch
import shutil
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.dataset import (
    IMAGE_SUFFIXES,
    JOINT_COLUMNS,
    KINDS,
    POSED_ROLES,
    DatasetWriter,
    check_image_file,
    image_header,
    photo_files,
)
from bench.errors import BenchError, ConfigError

ROLES = ("rig", *POSED_ROLES)
#: roles of frames that have joint readings but no photo
READINGS_ONLY_ROLES = ("task",)


@dataclass
class InitResult:
    """What :func:`init_dataset` wrote: the folder, its kind and how many views (by role), tracker points."""

    root: Path
    kind: str
    views: int
    roles: dict = field(default_factory=dict)
    tracker_points: int = 0


class _RawDatasetWriter(DatasetWriter):
    """:class:`~bench.dataset.DatasetWriter` that also takes a photo *file*, copied as it is (no re-encoding), and
    joint readings already in the dataset's unit (degrees: the user's numbers are not rounded through radians)."""

    def add_photo(self, name: str, src: Path, q_deg=None, role: str = "", region: str = "") -> None:
        rel = f"images/{name}{src.suffix.lower()}"
        shutil.copyfile(src, self.path(rel))
        self._add_raw(name, rel, q_deg, role, region)

    def add_readings(self, name: str, q_deg, role: str) -> None:
        self._add_raw(name, None, q_deg, role, "")

    def _add_raw(self, name, rel, q_deg, role, region) -> None:
        self._add_entry(name, rel, role, "", region)
        if q_deg is not None:
            self._joints.append([name, *np.asarray(q_deg, dtype=float).reshape(len(JOINT_COLUMNS))])


def parse_roles(items, flag: str = "--role") -> list:
    """``[(role, pattern)]`` from ``--role ROLE=PATTERN`` strings (``flag="--region"``: ``[(region, pattern)]``
    from ``--region NAME=PATTERN``, any name); one-line BenchError for a malformed one."""
    out = []
    for item in items or []:
        role, sep, pattern = str(item).partition("=")
        role, pattern = role.strip(), pattern.strip()
        if not sep or not pattern or not role:
            raise BenchError(f"{flag} {item!r}: expected {'ROLE' if flag == '--role' else 'NAME'}=PATTERN, e.g. "
                             + ("rig='rig*'" if flag == "--role" else "left='left_*'"))
        if flag == "--role" and role not in ROLES:
            raise BenchError(f"--role {item!r}: unknown role {role!r} (one of {', '.join(ROLES)})")
        out.append((role, pattern))
    return out


def _role_of(name: str, roles: list, where: str, flag: str = "--role") -> str:
    """The one role (or region) whose pattern ``name`` matches; a one-line error naming the view otherwise."""
    what = "roles" if flag == "--role" else "regions"
    hits = sorted({r for r, pat in roles if fnmatch.fnmatchcase(name, pat)})
    if len(hits) > 1:
        raise ConfigError(where, name, f"matches the patterns of several {what} ({', '.join(hits)})")
    if not hits:
        pats = ", ".join(f"{r}={p}" for r, p in roles)
        raise ConfigError(where, name, f"matches no {flag} pattern ({pats})")
    return hits[0]


def _photos(folder: Path) -> dict:
    """``{view name: file}`` of the photos in ``folder`` (sorted by name); checks headers and equal sizes."""
    if not folder.is_dir():
        raise ConfigError(folder, "<folder>", "not found (--images: the folder of photos)")
    files = photo_files(folder)
    if not files:
        raise ConfigError(folder, "<folder>", f"no photos ({', '.join(IMAGE_SUFFIXES)})")
    out, size = {}, None
    for f in files:
        if f.stem in out:
            raise ConfigError(f, "<file>", f"two photos for view {f.stem!r} ({out[f.stem].name}, {f.name})")
        check_image_file(f)
        _, w, h = image_header(f)
        if size is None:
            size = (w, h, f.name)
        elif (w, h) != size[:2]:
            raise ConfigError(f, "<size>", f"{w}x{h} px, {size[2]} is {size[0]}x{size[1]} px: one camera takes one "
                                           "size")
        out[f.stem] = f
    return out


def _joint_log(path: Path, units: str | None):
    """``{view: (q_deg (6,), line)}`` from a joint log, through the importer's parser and checks."""
    from bench.robot.importers import _check_joints, _read_table

    try:
        table = _read_table(path, "joints", units)["joint"]
    except ConfigError as exc:  # the importer's own command calls the flag --units
        raise ConfigError(exc.source, exc.field, exc.problem.replace("pass --units", "pass --joint-units")) from None
    q_deg = _check_joints(table)
    return {n: (q, ln) for n, q, ln in zip(table.names, q_deg, table.lines, strict=True)}


def init_dataset(out, images=None, joints=None, joint_units: str | None = None, tracker=None,
                 tracker_units: str | None = None, tracker_joints=None, tracker_joint_units: str | None = None,
                 robot=None, camera=None, roles=None, kind: str | None = None, target: dict | None = None,
                 name: str | None = None, regions=None) -> InitResult:
    """Build a dataset folder from raw files (module docstring); returns what was written.

    Parameters
    ----------
    out : path
        The dataset folder to create (absent, or an empty folder).
    images : path, optional
        Folder of photos (JPEG/PNG), one per view.
    joints : path, optional
        Joint log with one row per view (key = the photo's stem or file name) and per readings-only frame.
    joint_units, tracker_units, tracker_joint_units : str, optional
        Units when the files do not state them (``deg``/``rad``; ``mm``/``m``).
    tracker, tracker_joints : path, optional
        Laser-tracker export, and a joint log for its points when the export has no joint columns.
    robot, camera : path, optional
        Nominal robot file (``models/ta40.yaml`` format) and camera file (``camera.yaml``).
    roles : list of str, optional
        ``ROLE=PATTERN`` items (module docstring).
    kind : {"in_situ", "camera_calibration", "kinematic"}, optional
        Default: ``in_situ`` with photos and a joint log, ``camera_calibration`` with photos alone, ``kinematic``
        with a tracker export alone.
    target : dict, optional
        :func:`bench.camera.calibrate_dataset.target_spec` of the calibration target -> ``target.yaml``.
    name : str, optional
        The dataset's name (default: the folder's name).
    regions : list of str, optional
        ``NAME=PATTERN`` items: the region of each reference, surrounding and locate view (module docstring).
    """
    from bench.camera.calibrate_dataset import target_yaml_text

    out = Path(out)
    empty_out = out.is_dir() and not any(out.iterdir())
    if out.exists() and not empty_out:
        what = ("a file" if not out.is_dir() else
                f"a non-empty folder (holds {sorted(p.name for p in out.iterdir())[0]!r})")
        raise BenchError(f"--out {out}: is {what}; a dataset is only written into a new or empty folder")
    if images is None and tracker is None:
        raise BenchError("nothing to put in the dataset: give --images (photos) and/or --tracker (a tracker export)")
    if joints is not None and images is None:
        raise BenchError("--joints: the joint log's rows name photos; give --images too")
    if kind is None:
        kind = "kinematic" if images is None else ("in_situ" if joints is not None else "camera_calibration")
    if kind not in KINDS or kind == "xy_table":
        raise BenchError(f"--kind: expected in_situ, camera_calibration or kinematic, got {kind!r}")
    role_list = parse_roles(roles)
    region_list = parse_roles(regions, "--region")
    if region_list and not role_list:
        raise BenchError("--region names the regions of the survey's views: give their --role patterns too")

    photos = _photos(Path(images)) if images is not None else {}
    readings = _joint_log(Path(joints), joint_units) if joints is not None else {}
    jname = str(joints)
    # rows of the joint log name a photo by its stem or its file name
    by_key = {}
    for key, (q, ln) in readings.items():
        stem = next((s for s, f in photos.items() if key in (s, f.name)), None)
        view = stem if stem is not None else (Path(key).stem if Path(key).suffix.lower() in IMAGE_SUFFIXES else key)
        if view in by_key:
            raise ConfigError(jname, f"line {ln}", f"a second row for view {view!r} (first on line {by_key[view][1]})")
        by_key[view] = (q, ln)
    view_roles = {v: _role_of(v, role_list, str(images) if v in photos else jname) if role_list else ""
                  for v in sorted(set(photos) | set(by_key))}
    view_regions = {v: _role_of(v, region_list, str(images) if v in photos else jname, "--region")
                    for v, r in view_roles.items() if region_list and r in ("reference", "surround", "locate")}
    for v, (_, ln) in by_key.items():
        if v not in photos and view_roles[v] not in READINGS_ONLY_ROLES:
            raise ConfigError(jname, f"line {ln}", f"view {v!r}: no photo {v} (.jpg, .jpeg, .png) in {images} (a "
                                                   f"row without a photo is only allowed for role task)")
    if kind == "in_situ":
        for v in photos:
            if v not in by_key:
                raise ConfigError(images, f"{photos[v].name}", f"no row for view {v!r} in the joint log {jname}: an "
                                                               "in-situ view is posed by the arm's readings")
    if any(r == "rig" for r in view_roles.values()) and target is None:
        raise BenchError("views with role rig need the calibration target: give --target chessboard --inner WxH "
                         "--square-mm S (or --target two_plane_rig --size-mm S ...)")

    robot_model = None
    if robot is not None:
        from bench.robot.model import load_robot

        robot_model = load_robot(robot)
        if robot_model.n != len(JOINT_COLUMNS):
            raise ConfigError(robot, "joints", f"{robot_model.n} joints; a dataset's joint log has "
                                               f"{len(JOINT_COLUMNS)}")
        lo, hi = np.rad2deg(robot_model.q_min), np.rad2deg(robot_model.q_max)
        for v, (q, ln) in by_key.items():
            bad = np.flatnonzero((q < lo - 1e-6) | (q > hi + 1e-6))
            if bad.size:
                j = int(bad[0])
                raise ConfigError(jname, f"line {ln} ({v}), q{j + 1}", f"{q[j]:g} deg is outside joint {j + 1}'s "
                                                                       f"limits [{lo[j]:g}, {hi[j]:g}] deg of {robot}")
    if camera is not None:
        from bench.camera.io import read_camera_yaml

        cam = read_camera_yaml(camera)
        for f in photos.values():
            check_image_file(f, expected_size=cam.size)

    if empty_out:
        out.rmdir()  # DatasetWriter renames the finished dataset into place
    n_tracker = 0
    with _RawDatasetWriter(out, kind=kind, name=name or out.name,
                           created_by="bench dataset init") as w:
        for v in sorted(set(photos) | set(by_key)):
            q = by_key[v][0] if v in by_key else None
            if v in photos:
                w.add_photo(v, photos[v], q, view_roles[v], view_regions.get(v, ""))
            else:
                w.add_readings(v, q, view_roles[v])
        if tracker is not None:
            from bench.robot.importers import import_tracker

            with tempfile.TemporaryDirectory() as tmp:
                res = import_tracker(tracker, Path(tmp) / "tracker.csv", tracker_units, tracker_joints,
                                     tracker_joint_units)
                w.write_text("tracker.csv", (Path(tmp) / "tracker.csv").read_text())
                n_tracker = res.rows
        if robot is not None:
            shutil.copyfile(robot, w.path("robot.yaml"))
        if camera is not None:
            shutil.copyfile(camera, w.path("camera.yaml"))
        if target is not None:
            w.write_text("target.yaml", target_yaml_text(target))
    counts = dict(Counter(r or "(none)" for r in view_roles.values()))
    from bench.dataset import load_dataset

    try:
        load_dataset(out)  # what was written reads back (the dataset's own checks)
    except BenchError:
        shutil.rmtree(out)  # this call created it: no half-checked dataset is left
        raise
    return InitResult(out, kind, len(view_roles), counts, n_tracker)
