"""The dataset: the seam between the bench and the pipeline (``shared/design.md``).

A dataset is a folder that a real robot campaign or the simulator writes::

    manifest.yaml   format, kind of campaign, units, the views (name, image file, role, notes, and for an in-situ
                    survey over several regions of the scene its ``region``); a view without an image file is a
                    frame of joint readings only (e.g. a taught tool pose, role ``task``)
    images/         lossless PNG views named in the manifest
    joints.csv      view, q1_deg ... q6_deg        (joint *readings*, robot campaigns)
    table.csv       view, x_mm, z_mm, rot_deg      (x-y table readings, table campaigns)
    tracker.csv     point, x_mm, y_mm, z_mm, q1_deg ... q6_deg   (kinematic campaigns)
    camera.yaml     nominal (or calibrated) camera: OpenCV FileStorage keys + model name
    robot.yaml      nominal DH + joint limits (``models/ta40.yaml`` format)
    housing.yaml    (cameras in water) the housing's datasheet: lens-to-glass distance and its tolerance, glass
                    thickness and index, the water's index (:func:`bench.camera.io.read_housing_yaml`)
    truth/          simulated datasets only; never read here (the evaluator's business)

This module reads the public part (:func:`load_dataset`) and writes any part atomically (:class:`DatasetWriter`:
everything goes to a temporary sibling folder that is renamed into place only when complete, so an interrupted or
failed write leaves no half-written dataset). Units in files are mm and degrees (unit in every column name); what
:func:`load_dataset` returns is SI (m, rad). Every malformed file or field is a one-line :class:`ConfigError`
naming the file and the field.
"""

from __future__ import annotations

import csv
import io
import os
import shutil
import tempfile
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import yaml
from pydantic import Field, field_validator, model_validator

from bench.config import KeyProblem, MmDeg, Section, parse, section
from bench.errors import ConfigError
from bench.fileio import (
    check_output_dir,
    check_replaceable,
    fix_mkdtemp_mode,
    mark_output_dir,
    output_marker,
    read_yaml,
    record_output_entries,
)

FORMAT = "insitu-bench-dataset/1"
KINDS = ("in_situ", "camera_calibration", "xy_table", "kinematic")
#: View roles that the in-situ pipeline poses through the arm kinematics: each needs a row in ``joints.csv``.
POSED_ROLES = ("reference", "surround", "locate", "task")
JOINT_COLUMNS = tuple(f"q{i}_deg" for i in range(1, 7))
TABLE_COLUMNS = ("x_mm", "z_mm", "rot_deg")
TRACKER_COLUMNS = ("x_mm", "y_mm", "z_mm")
#: Largest image decoded (pixels): 100 Mpx, beyond any camera the bench or a subsea system uses, so a forged or
#: corrupt header (e.g. 20000 x 20000) is refused from its first bytes instead of allocating gigabytes.
MAX_IMAGE_PIXELS = 100_000_000
#: Largest image file of a format whose header is not read here (bytes).
MAX_IMAGE_BYTES = 512 * 2**20
#: Formats whose header Pillow reads here (told by the file's signature, not its name); OpenCV decodes them all.
_HEADER_FORMATS = ("PNG", "JPEG", "TIFF", "BMP", "WEBP")
_PILLOW_LIMIT = threading.Lock()


class _ViewEntry(Section):
    name: Annotated[str, Field(min_length=1)]
    image: str | None = None
    role: str = ""
    notes: str = ""
    #: in-situ views: the part of the scene a reference view, its surrounding views and its locate views share
    #: (``""``: the only one); :func:`bench.vision.locate_dataset.locate_dataset` maps and locates each region
    region: str = ""

    @field_validator("image", mode="before")
    @classmethod
    def _file_name(cls, v):
        if v is not None and (not isinstance(v, str) or not v):
            raise ValueError(f"expected a file name, got {v!r}")
        return v


class Manifest(Section):
    """``manifest.yaml``: the format, the kind of campaign, units, the views (see the module docstring)."""

    format: Literal[FORMAT]
    kind: Literal[KINDS]
    units: MmDeg = section(MmDeg)
    name: str | None = None
    notes: str = ""
    created_by: str = ""
    camera: str | None = None
    robot: str | None = None
    views: list[_ViewEntry] | None = None

    @model_validator(mode="after")
    def _distinct_names(self):
        seen = set()
        for i, v in enumerate(self.views or []):
            if v.name in seen:
                raise KeyProblem(f"views[{i}].name", f"duplicate view {v.name!r}")
            seen.add(v.name)
        return self


#: the file suffixes a plain folder of photos is read by (any case)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def photo_files(folder: Path) -> list:
    """The photos of ``folder`` (files with an :data:`IMAGE_SUFFIXES` suffix, any case), sorted by name."""
    return sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def _open_header(path: Path, formats=_HEADER_FORMATS):
    """``PIL.Image.open`` (lazy: reads the header, not the image data) without Pillow's own pixel limit.

    Pillow refuses a huge header without saying the size it claims; :func:`check_image_file` applies
    :data:`MAX_IMAGE_PIXELS` to the size read here instead. ``PIL.UnidentifiedImageError`` for a format not in
    ``formats`` (None: any Pillow reads).
    """
    from PIL import Image

    with _PILLOW_LIMIT:  # Pillow's limit is a module global: lifted for this call only
        limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
        try:
            return Image.open(path, formats=formats)
        finally:
            Image.MAX_IMAGE_PIXELS = limit


def image_header(path: Path):
    """``(format, width, height)`` from the header of an image file (Pillow's format name: ``"PNG"``, ``"JPEG"``,
    ...), ``None`` for a format not in :data:`_HEADER_FORMATS`.

    One-line :class:`ConfigError` for an empty file, and for a file named like one of those formats that Pillow
    cannot identify as it (wrong signature, or a header corrupt or cut short, e.g. a PNG without IHDR, a JPEG
    without a frame header). Reads the header, never the image data. A PNG whose IHDR chunk is sound but whose
    next chunks Pillow cannot read gives its IHDR size, so that :func:`check_image_file` judges the file's size first.
    """
    from PIL import Image, UnidentifiedImageError

    if path.stat().st_size == 0:
        raise ConfigError(path, "<file>", "empty file")
    try:
        im = _open_header(path)
    except UnidentifiedImageError:
        with path.open("rb") as f:
            head = f.read(24)
        if head.startswith(b"\x89PNG\r\n\x1a\n") and head[12:16] == b"IHDR":  # IHDR: first chunk, fixed place
            return "PNG", int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        fmt = Image.registered_extensions().get(path.suffix.lower())
        if fmt in _HEADER_FORMATS:
            raise ConfigError(path, "<header>", f"not a {fmt} file: wrong signature, or a header corrupt or cut "
                                                "short") from None
        return None
    except (OSError, ValueError, EOFError) as exc:
        raise ConfigError(path, "<header>", f"unreadable image header ({exc})") from None
    with im:
        return im.format, im.width, im.height


def check_image_file(path: Path, expected_size=None) -> None:
    """Refuse, without decoding it, an image file that is empty, corrupt, cut short, huge, or not of ``expected_size``.

    Limits: :data:`MAX_IMAGE_PIXELS`; a file larger than 8 bytes per pixel plus 1 MB (more than 16-bit RGBA stored
    raw) is not an image of the size its header claims; formats whose header is not read up to
    :data:`MAX_IMAGE_BYTES`. Then Pillow's ``verify()`` walks the file (a PNG's chunks up to IEND, each against its
    CRC) without decoding: a file cut short or a chunk failing its CRC is refused here. A PNG of 16 bits per sample
    is refused from its header (Pillow would decode a 16-bit colour PNG to 8 bits without a word).
    """
    from PIL import UnidentifiedImageError

    hdr = image_header(path)
    size = path.stat().st_size
    if hdr is None:
        if size > MAX_IMAGE_BYTES:
            raise ConfigError(path, "<file>", f"{size / 2**20:.0f} MB: larger than any image the bench reads "
                                              f"({MAX_IMAGE_BYTES / 2**20:.0f} MB)")
        return
    fmt, w, h = hdr
    if fmt == "PNG":
        with path.open("rb") as f:
            head = f.read(26)
        if head[12:16] == b"IHDR" and len(head) > 24 and head[24] == 16:  # IHDR: width, height, bit depth
            raise ConfigError(path, "<file>", "expected an 8-bit image, got a PNG of 16 bits per sample")
    if w <= 0 or h <= 0:
        raise ConfigError(path, "<header>", f"{fmt} header gives a {w}x{h} image: corrupt")
    if w * h > MAX_IMAGE_PIXELS:
        raise ConfigError(path, "<size>", f"{fmt} header claims {w}x{h} = {w * h / 1e6:.0f} Mpx, more than "
                                          f"{MAX_IMAGE_PIXELS / 1e6:.0f} Mpx: refused before decoding")
    if expected_size is not None and (w, h) != tuple(expected_size):
        raise ConfigError(path, "<size>", f"image is {w}x{h}, the camera file says {expected_size[0]}x"
                                          f"{expected_size[1]}")
    if size > 8 * w * h + 2**20:
        raise ConfigError(path, "<file>", f"{size / 2**20:.1f} MB for a {w}x{h} image: not an image of that size")
    try:
        with _open_header(path) as im:
            im.verify()
    except SyntaxError as exc:  # a chunk failing its CRC (Pillow: "broken PNG file (bad header checksum in ...)")
        raise ConfigError(path, "<file>", f"{fmt} file corrupt: {exc}") from None
    except UnidentifiedImageError:
        raise ConfigError(path, "<file>", f"{fmt} file corrupt or cut short after its header") from None
    except (OSError, EOFError, ValueError) as exc:
        raise ConfigError(path, "<file>", f"{fmt} cut short: truncated or corrupt (Pillow: {exc})") from None


#: Pillow modes read as grey ``(H, W)``; 16/32-bit and float modes are refused; every other mode becomes RGB.
_GREY_MODES = ("L", "1", "LA", "La")
_DEEP_MODES = ("I", "I;16", "I;16B", "I;16L", "I;16N", "F")


def read_image(path: Path) -> np.ndarray:
    """Decode an image file through Pillow: ``uint8 (H, W, 3)`` RGB, or ``(H, W)`` grey for a grey file (alpha
    dropped, palettes expanded; the raw sensor layout, EXIF orientation not applied).

    One-line :class:`ConfigError` naming the file for a file Pillow cannot decode (corrupt data, cut short: the
    decoder's own words) and for a 16/32-bit or float image. Pillow's pixel limit is lifted: call
    :func:`check_image_file` first, which applies :data:`MAX_IMAGE_PIXELS` to the header's size.
    """
    import zlib

    from PIL import UnidentifiedImageError

    try:
        with _open_header(path, formats=None) as im:
            im.load()
            if im.mode in _DEEP_MODES:
                raise ConfigError(path, "<file>", f"expected an 8-bit image, got Pillow mode {im.mode!r}")
            im = im.convert("L") if im.mode in _GREY_MODES else im.convert("RGB") if im.mode != "RGB" else im
            img = np.asarray(im)
    except UnidentifiedImageError:
        raise ConfigError(path, "<file>", "not an image file Pillow can read") from None
    except (OSError, SyntaxError, ValueError, EOFError, zlib.error) as exc:
        raise ConfigError(path, "<file>", f"not readable ({exc})") from None
    if img.size == 0:
        raise ConfigError(path, "<file>", "empty image")
    return img


@dataclass(frozen=True)
class View:
    """One image of the campaign: its file, role, and the readings taken with it (SI)."""

    name: str
    image_path: Path | None  # None: a frame of readings only (no image)
    role: str = ""
    notes: str = ""
    q: np.ndarray | None = None  # joint readings (rad), (6,)
    table: np.ndarray | None = None  # x-y table readings (m, m, rad): x, z, rotation about y
    region: str = ""  # in-situ views: the region of the scene (manifest ``region``; "" the only one)

    def image(self, expected_size=None) -> np.ndarray:
        """The image as ``uint8 (H, W, 3)`` RGB (or ``(H, W)`` grey); one-line error if missing or unreadable.

        ``expected_size`` = ``(width, height)`` checks the image against the camera file.
        """
        if self.image_path is None:
            raise ConfigError(self.name, "image", "this view is a frame of readings only: it has no image")
        if not self.image_path.is_file():
            raise ConfigError(self.image_path, "<file>", f"image of view {self.name!r} not found")
        try:
            check_image_file(self.image_path, expected_size)
            img = read_image(self.image_path)
        except ConfigError as exc:
            raise ConfigError(exc.source, exc.field, f"image of view {self.name!r}: {exc.problem}") from None
        if expected_size is not None and (img.shape[1], img.shape[0]) != tuple(expected_size):
            raise ConfigError(self.image_path, "<size>", f"image is {img.shape[1]}x{img.shape[0]}, the camera file "
                                                         f"says {expected_size[0]}x{expected_size[1]}")
        return img


@dataclass(frozen=True)
class Dataset:
    """The public part of a dataset folder (see the module docstring); SI units."""

    root: Path
    name: str
    kind: str
    views: tuple
    camera_path: Path | None
    robot_path: Path | None
    tracker: dict | None = None  # {"point": names, "p": (N, 3) m, "q": (N, 6) rad}
    notes: str = ""
    extra: dict = field(default_factory=dict)

    def view(self, name: str) -> View:
        """The view called ``name``; one-line error naming the manifest if there is none."""
        for v in self.views:
            if v.name == name:
                return v
        raise ConfigError(self.root / "manifest.yaml", "views", f"no view named {name!r}")

    def camera(self):
        """The camera file as a :class:`bench.camera.model.CameraModel`."""
        from bench.camera.io import read_camera_yaml

        if self.camera_path is None:
            raise ConfigError(self.root / "manifest.yaml", "camera", "this dataset has no camera file")
        return read_camera_yaml(self.camera_path)

    def robot(self):
        """The robot file as a :class:`bench.robot.model.Robot` (nominal DH and limits)."""
        from bench.robot.model import load_robot

        if self.robot_path is None:
            raise ConfigError(self.root / "manifest.yaml", "robot", "this dataset has no robot file")
        return load_robot(self.robot_path)

    def joint_readings(self, names=None) -> np.ndarray:
        """Joint readings (rad) of the named views (default all), shape (k, 6)."""
        views = self.views if names is None else [self.view(n) for n in names]
        missing = [v.name for v in views if v.q is None]
        if missing:
            raise ConfigError(self.root / "joints.csv", missing[0], "no joint readings for this view")
        return np.stack([v.q for v in views])


# ------------------------------------------------------------------------------------------------ reading


def _read_csv(path: Path, key: str, columns) -> dict:
    """Rows of a CSV with a key column and numeric ``columns``: ``{key_value: ndarray(len(columns))}`` (file units)."""
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise ConfigError(path, "<file>", "not a text CSV file") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise ConfigError(path, "<file>", "empty")
    reader = csv.DictReader(lines)
    header = reader.fieldnames or []
    for col in (key, *columns):
        if col not in header:
            unitless = col.rsplit("_", 1)[0]
            hint = " (give the unit in the column name)" if unitless in header else ""
            raise ConfigError(path, col, f"missing column{hint}; header is {', '.join(header)}")
    extra = [c for c in header if c not in (key, *columns)]
    if extra:
        raise ConfigError(path, extra[0], f"unknown column (expected {', '.join((key, *columns))})")
    out = {}
    for i, row in enumerate(reader, start=2):
        if None in row or any(v is None for v in row.values()):
            n = len(header) + len(row.get(None) or []) - sum(v is None for v in row.values())
            raise ConfigError(path, f"line {i}", f"{n} values for the {len(header)} columns of the header")
        name = (row.get(key) or "").strip()
        if not name:
            raise ConfigError(path, f"line {i}", f"empty {key!r}")
        if name in out:
            raise ConfigError(path, f"line {i}", f"duplicate {key} {name!r}")
        vals = []
        for col in columns:
            raw = row.get(col)
            try:
                v = float(raw)
            except (TypeError, ValueError):
                raise ConfigError(path, f"line {i} ({name}).{col}", f"not a number: {raw!r}") from None
            if not np.isfinite(v):
                raise ConfigError(path, f"line {i} ({name}).{col}", "NaN or inf")
            vals.append(v)
        out[name] = np.array(vals)
    return out


def _check_degrees(path: Path, rows: dict, columns) -> None:
    """Reject angles that cannot be degrees; warn when every reading looks like radians in a ``*_deg`` column."""
    angles = np.array([r[: len(columns)] for r in rows.values()])
    if angles.size and np.abs(angles).max() > 720:
        i, j = np.unravel_index(np.argmax(np.abs(angles)), angles.shape)  # the row and column that says so
        raise ConfigError(path, f"{list(rows)[i]}.{columns[j]}", f"|angle| {abs(angles[i, j]):.1f} > 720 deg: not "
                                                                 "degrees")
    if angles.size >= 18 and np.abs(angles).max() <= np.pi + 1e-6 and np.abs(angles).max() > 0.5:
        warnings.warn(f"{path}: every angle lies within +-pi although the columns are *_deg: "
                      "were radians written where degrees belong?", stacklevel=3)


def _require_degrees(path: Path, rows: dict, columns) -> None:
    """:func:`_check_degrees` with its warning made an error: a dataset's readings are the pipeline's input, and a
    campaign whose every joint reading lies within +-3.14 deg is not one (radians written as degrees)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _check_degrees(path, rows, columns)
    if caught:
        raise ConfigError(path, f"{columns[0]} ... {columns[-1]}", "every reading lies within +-pi although the "
                                                                   "columns are *_deg: radians written where degrees "
                                                                   "belong?")


def load_dataset(root) -> Dataset:
    """Read a dataset folder (the public part only; ``truth/`` is never opened).

    Parameters
    ----------
    root : path-like
        The dataset folder (the one holding ``manifest.yaml``).

    Returns
    -------
    Dataset
        Views with their joint or table readings in SI units (rad, m).
    """
    root = Path(root)
    mpath = root / "manifest.yaml"
    if not root.is_dir():
        raise ConfigError(root, "<folder>", "dataset folder not found")
    if not mpath.is_file():  # a run's folder or the images folder given for the dataset: name the one meant
        near = [d for d in (root / "dataset", root.parent) if (d / "manifest.yaml").is_file()]
        raise ConfigError(mpath, "<file>", "not found: not a dataset folder" + (f" (did you mean {near[0]}?)"
                                                                                 if near else ""))
    man = parse(Manifest, read_yaml(mpath), mpath)
    kind = man["kind"]

    joints = _read_csv(root / "joints.csv", "view", JOINT_COLUMNS) if (root / "joints.csv").is_file() else {}
    if joints:
        _require_degrees(root / "joints.csv", joints, JOINT_COLUMNS)
    table = _read_csv(root / "table.csv", "view", TABLE_COLUMNS) if (root / "table.csv").is_file() else {}

    views, seen = [], set()
    for i, v in enumerate(man["views"] or []):
        name, image = v["name"], v["image"]
        seen.add(name)
        q = np.deg2rad(joints[name]) if name in joints else None
        t = table.get(name)
        if t is not None:
            t = np.array([t[0] * 1e-3, t[1] * 1e-3, np.deg2rad(t[2])])
        if image is None and q is None and t is None:
            raise ConfigError(mpath, f"views[{i}].image", "missing (a view needs an image or readings)")
        views.append(View(name, None if image is None else root / image, v["role"], v["notes"], q, t, v["region"]))
    if kind == "in_situ":
        unposed = [v for v in views if v.role in POSED_ROLES and v.q is None]
        if unposed:
            raise ConfigError(root / "joints.csv", unposed[0].name, f"no joint readings for this view (role "
                                                                    f"{unposed[0].role!r} is posed by the arm)")
    for src, rows in (("joints.csv", joints), ("table.csv", table)):
        orphan = sorted(set(rows) - seen)
        if orphan:
            raise ConfigError(root / src, orphan[0], "readings for a view that the manifest does not list")

    tracker = None
    if (root / "tracker.csv").is_file():
        rows = _read_csv(root / "tracker.csv", "point", TRACKER_COLUMNS + JOINT_COLUMNS)
        arr = np.array(list(rows.values()))
        _require_degrees(root / "tracker.csv", {k: r[3:] for k, r in rows.items()}, JOINT_COLUMNS)
        tracker = {"point": list(rows), "p": arr[:, :3] * 1e-3, "q": np.deg2rad(arr[:, 3:])}

    def _opt_path(key):
        value = man[key]
        if value is None:
            return None
        p = root / str(value)
        if not p.is_file():
            raise ConfigError(mpath, key, f"file {value!r} not found in the dataset")
        return p

    return Dataset(root, man["name"] or root.name, kind, tuple(views), _opt_path("camera"), _opt_path("robot"),
                   tracker, man["notes"])


# ------------------------------------------------------------------------------------------------ writing


def _csv_text(header, rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow([x if isinstance(x, str) else repr(float(x)) for x in r])
    return buf.getvalue()


class DatasetWriter:
    """Write a dataset atomically: into a temporary sibling folder, renamed to ``root`` on success.

    Use as a context manager::

        with DatasetWriter(out, kind="in_situ", name="demo") as w:
            w.add_view("ref", rgb, q=q_read, role="reference")
            w.write_text("camera.yaml", text)
        # out/ now exists, complete; on an exception nothing is left behind

    The folder is marked as the output of ``command`` (:mod:`bench.fileio`: ``.bench-output.json``) for
    ``identity`` (default: the dataset's name). ``root`` may be absent or an empty folder; ``overwrite=True`` also
    replaces a previous output of the same command and identity, only once the new one is complete; ``force=True``
    one of the same command with another identity. Anything else at ``root`` - a file, a folder bench did not write,
    another command's output - is refused (:class:`~bench.fileio.OutputRefused`) when the writer is created, before
    any work.
    """

    def __init__(self, root, kind: str, name: str | None = None, notes: str = "", created_by: str = "",
                 overwrite: bool = False, command: str = "dataset", force: bool = False, identity: str | None = None):
        if kind not in KINDS:
            raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
        self.root = Path(root)
        self.kind, self.name, self.notes, self.created_by = kind, name or self.root.name, notes, created_by
        self.command, self.identity = command, identity or self.name
        marker = output_marker(self.root) if self.root.is_dir() else None
        if marker and marker["command"] == command and not (overwrite or force):
            raise ConfigError(self.root, "<folder>", "already exists (pass --overwrite to replace it)")
        self.overwrite, self.force = overwrite, force
        self._check_root()
        self.tmp: Path | None = None
        self._views: list[dict] = []
        self._joints: list = []
        self._table: list = []
        self.camera_file: str | None = None
        self.robot_file: str | None = None

    def _check_root(self) -> None:
        """``root`` may be written: absent, empty, or an output it may replace (:func:`~bench.fileio.check_output_dir`);
        one it replaces is replaced whole, so nothing of someone else's may be in it."""
        if check_output_dir(self.root, self.command, force=self.force, identity=self.identity,
                            option="dataset folder") in ("own", "replace"):
            check_replaceable(self.root, "dataset folder")

    def __enter__(self) -> DatasetWriter:
        self.root.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = fix_mkdtemp_mode(tempfile.mkdtemp(dir=self.root.parent, prefix=f".{self.root.name}.", suffix=".tmp"))
        (self.tmp / "images").mkdir()
        return self

    def path(self, relative: str) -> Path:
        """Absolute path inside the temporary folder (for files written by other code); parents created."""
        p = self.tmp / relative
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def write_text(self, relative: str, text: str) -> None:
        """Write a text file inside the dataset (e.g. ``camera.yaml``, ``truth/truth.yaml``)."""
        self.path(relative).write_text(text)

    def add_view(self, name: str, image: np.ndarray | None, q=None, table=None, role: str = "",
                 notes: str = "", region: str = "") -> None:
        """Add a view: ``image`` uint8 RGB (H, W, 3) or grey (H, W), saved as PNG; readings in SI.

        ``q`` joint readings (rad, (6,)); ``table`` x-y table readings ``(x m, z m, rotation rad)``.
        ``image=None`` records a frame of readings only (e.g. a taught tool pose). ``region``: an in-situ view's
        region of the scene (written only when not ``""``).
        """
        import cv2

        if any(v["name"] == name for v in self._views):
            raise ValueError(f"view {name!r}: added twice")
        rel = None
        if image is None:
            if q is None and table is None:
                raise ValueError(f"view {name!r}: needs an image or readings")
        else:
            image = np.asarray(image)
            if image.dtype != np.uint8 or image.ndim not in (2, 3):
                raise ValueError(f"view {name!r}: image must be uint8 (H, W[, 3]), got {image.dtype} {image.shape}")
            rel = f"images/{name}.png"
            bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
            if not cv2.imwrite(str(self.tmp / rel), bgr):
                raise OSError(f"could not write {self.tmp / rel}")
        self._add_entry(name, rel, role, notes, region)
        if q is not None:
            q = np.asarray(q, dtype=float).reshape(6)
            self._joints.append([name, *np.rad2deg(q)])
        if table is not None:
            x, z, rot = np.asarray(table, dtype=float).reshape(3)
            self._table.append([name, x * 1e3, z * 1e3, np.rad2deg(rot)])

    def _add_entry(self, name: str, rel: str | None, role: str, notes: str, region: str) -> None:
        """The manifest's entry of a view: its name, then its image file, role, notes and region when given."""
        entry = {"name": name} if rel is None else {"name": name, "image": rel}
        entry.update((key, value) for key, value in (("role", role), ("notes", notes), ("region", region)) if value)
        self._views.append(entry)

    def write_tracker(self, points, p_tracker, q) -> None:
        """Tracker points (m, in the tracker frame) with the joint readings (rad) they were taken at."""
        p_tracker, q = np.asarray(p_tracker, float), np.asarray(q, float)
        rows = [[n, *(p * 1e3), *np.rad2deg(qq)] for n, p, qq in zip(points, p_tracker, q, strict=True)]
        self.write_text("tracker.csv", _csv_text(["point", *TRACKER_COLUMNS, *JOINT_COLUMNS], rows))

    def _finish(self) -> None:
        if self._joints:
            self.write_text("joints.csv", _csv_text(["view", *JOINT_COLUMNS], self._joints))
        if self._table:
            self.write_text("table.csv", _csv_text(["view", *TABLE_COLUMNS], self._table))
        man = {"format": FORMAT, "kind": self.kind, "name": self.name, "units": {"length": "mm", "angle": "deg"}}
        man.update((key, value) for key, value in (("created_by", self.created_by), ("notes", self.notes)) if value)
        for key, rel in (("camera", "camera.yaml"), ("robot", "robot.yaml")):
            if (self.tmp / rel).is_file():
                man[key] = rel
        man["views"] = self._views
        self.write_text("manifest.yaml", yaml.safe_dump(man, sort_keys=False))
        mark_output_dir(self.tmp, self.command, self.identity)
        record_output_entries(self.tmp)

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return False
        try:
            self._finish()
            self._check_root()  # again: the folder may have changed while the views were rendered
            if self.root.exists():
                old = self.root.with_name(f".{self.root.name}.old-{os.getpid()}")
                os.replace(self.root, old)
                os.replace(self.tmp, self.root)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(self.tmp, self.root)
        except BaseException:
            shutil.rmtree(self.tmp, ignore_errors=True)
            raise
        return False
