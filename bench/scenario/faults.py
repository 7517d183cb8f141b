"""``bench faults DATASET --out DIR``: inject the faults of a real dive into copies of a rendered in-situ dataset,
localise each with ``bench locate``'s pipeline, and score it against ``truth/`` (the bench side; the pipeline never
sees the truth).

Every fault is one function ``(dataset copy, calibrated files, rng) -> description`` that damages the copy as the dive
would (the lab calibration is done before the dive, on the clean dataset, unless the fault is the calibration):

======================  ================================================================================================
``clean``               nothing (the reference row)
``swap_images``         the images of the first locate view and the middle survey view exchanged
``duplicate_frame``     the second locate view's image replaced by a copy of the first's
``joint_log_shift``     the site views' joint readings shifted by one row (each view gets the next view's readings)
``joint_offset``        one joint reading of one site view (drawn) offset by 0.5 deg
``joint_offset_small``  one of joints 1-5 of one locate view (drawn) offset by 0.1 deg (an encoder glitch below
                        what the images alone show at once)
``mount_bent``          the camera mount bent after the lab calibration: 1 deg about a drawn axis, 5 mm along a drawn
                        direction (applied to the calibrated mount the pipeline uses: the same relative error)
``mount_knocked``       the camera turned on its mount *between* the survey and the localisation (a knock at the
                        structure): both locate images as the camera turned by 0.2 deg about a drawn axis sees the
                        scene (remapped through the calibrated camera model, its distortion included)
``air_calibration``     the camera file of an air calibration used underwater: focal length / 1.333 (n_water / n_air)
``focal_drift``         the housing's optics drifted since the lab: the camera file's focal length 1 % off, its
                        principal point 3 px off (temperature, pressure, a refocused lens)
``fouled_lens``         a smeared, darkened disc over a quarter of both locate images (a fouled port)
``motion_blur``         the first locate view blurred along a drawn direction (21 px linear kernel)
``turbid``              both locate images seen through 2 m more of turbid harbour water (Akkaynak-Treibitz model,
                        :mod:`bench.sim.medium`) with 2 DN of sensor noise
``new_growth``          growth since the survey: textured blobs covering ~30 % of the panel in both locate images
======================  ================================================================================================

Each faulted dataset is localised (:func:`bench.vision.locate_dataset.locate_dataset`) and scored: the true base
position and rotation errors, the integrity and protection levels, and whether the failure is *silent*: integrity
``ok`` while the position error exceeds the protection radius or :data:`SILENT_MM`, or the rotation error exceeds the
protection angle. ``DIR/faults.csv`` holds one row per fault, ``DIR/faults.json`` the same with the reasons.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import yaml

from bench.dataset import load_dataset
from bench.errors import ConfigError
from bench.fileio import atomic_write_text, claimed_output_dir, settings_identity
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert
from bench.scenario.results import pose_errors
from bench.vision.insitu import twin_map_config

#: A position error above this is a failure whatever the protection radius (the alert limit of the issue, mm).
SILENT_MM = 3.0
N_WATER = 1.333
#: the camera's turn on its mount between the survey and the localisation in ``mount_knocked`` (deg)
KNOCK_DEG = 0.2


def _site_views(ds):
    """The views the faults act on: the survey and locate views by role - of the first region when the dataset has
    several (the others stay intact: the localisation can leave the damaged region out)."""
    posed = [v for v in ds.views if v.role in ("reference", "surround", "locate")]
    first = posed[0].region if posed else ""
    roles = {r: [v.name for v in posed if v.role == r and v.region == first] for r in ("reference", "surround",
                                                                                        "locate")}
    if len(roles["locate"]) < 2 or not roles["surround"] or len(roles["reference"]) != 1:
        raise ConfigError(ds.root / "manifest.yaml", "views", "fault injection needs a reference view, surround views "
                                                             "and two locate views")
    return roles


def _img_path(root: Path, name: str) -> Path:
    return root / "images" / f"{name}.png"


def _read(root, name):
    img = cv2.imread(str(_img_path(root, name)), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ConfigError(_img_path(root, name), "image", "unreadable")
    return img


def _write(root, name, img):
    if not cv2.imwrite(str(_img_path(root, name)), img):
        raise ConfigError(_img_path(root, name), "image", "could not be written")


def _joints(root):
    rows = list(csv.reader(io.StringIO((root / "joints.csv").read_text())))
    return rows[0], rows[1:]


def _write_joints(root, header, rows):
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows([header, *rows])
    atomic_write_text(root / "joints.csv", buf.getvalue())


# --------------------------------------------------------------------------------------------------------- faults


def clean(root, roles, cal, rng):
    return "no fault"


def swap_images(root, roles, cal, rng):
    a, s = roles["locate"][0], roles["surround"][(len(roles["surround"]) - 1) // 2]
    ia, is_ = _read(root, a), _read(root, s)
    _write(root, a, is_)
    _write(root, s, ia)
    return f"images of {a} and {s} exchanged"


def duplicate_frame(root, roles, cal, rng):
    a, b = roles["locate"][:2]
    shutil.copyfile(_img_path(root, a), _img_path(root, b))
    return f"{b}.png replaced by a copy of {a}.png"


def joint_log_shift(root, roles, cal, rng):
    header, rows = _joints(root)
    site = [roles["reference"][0], *roles["surround"], *roles["locate"][:2]]
    idx = [i for i, r in enumerate(rows) if r[0] in site]
    values = [rows[i][1:] for i in idx]
    for k, i in enumerate(idx):
        rows[i] = [rows[i][0], *values[(k + 1) % len(values)]]
    _write_joints(root, header, rows)
    return f"joint readings of the {len(idx)} site views shifted by one row"


def _offset_joint(root, view: str, j: int, delta_deg: float) -> str:
    """Offset joint column ``j`` of ``view``'s readings in ``joints.csv`` by ``delta_deg``; the description."""
    header, rows = _joints(root)
    for r in rows:
        if r[0] == view:
            r[j] = repr(float(r[j]) + delta_deg)
    _write_joints(root, header, rows)
    return f"{view} {header[j]} offset by {delta_deg:+g} deg"


def joint_offset(root, roles, cal, rng):
    header, _ = _joints(root)
    site = [roles["reference"][0], *roles["surround"], *roles["locate"][:2]]
    view = site[int(rng.integers(len(site)))]
    j = int(rng.integers(1, len(header)))
    return _offset_joint(root, view, j, 0.5 * float(rng.choice([-1.0, 1.0])))


def joint_offset_small(root, roles, cal, rng):
    header, _ = _joints(root)
    view = roles["locate"][int(rng.integers(2))]
    j = int(rng.integers(1, len(header) - 1))  # joints 1-5: joint 6 does not move the camera on link 5
    return _offset_joint(root, view, j, 0.1 * float(rng.choice([-1.0, 1.0])))


def _random_unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def mount_bent(root, roles, cal, rng):
    from bench.robot.calibration_file import load_calibrated_robot, write_calibrated_robot

    robot, eps, T_mount = load_calibrated_robot(cal["robot"])
    axis, direction = _random_unit(rng), _random_unit(rng)
    bend = homogeneous(rotation_vector_to_matrix(axis * np.deg2rad(1.0)), direction * 0.005)
    path = root.parent / "calibrated_bent" / "robot.yaml"
    # the pipeline keeps the lab mount while the true one is bent: the same as believing the bent-back one
    write_calibrated_robot(path, cal["robot"], robot, eps, T_mount @ invert(bend),
                           notes="FAULT: the lab mount; the camera was bent by 1 deg, 5 mm since")
    cal["robot"] = path
    return f"mount bent by 1 deg about {np.round(axis, 2).tolist()} and 5 mm along {np.round(direction, 2).tolist()}"


def mount_knocked(root, roles, cal, rng):
    from bench.camera.io import read_camera_yaml

    cam = read_camera_yaml(cal["camera"])
    axis = _random_unit(rng)
    R = rotation_vector_to_matrix(axis * np.deg2rad(KNOCK_DEG))  # the turned camera's axes in the old camera frame
    for name in roles["locate"][:2]:
        img = _read(root, name)
        h, w = img.shape[:2]
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        # pixel uv of the turned camera sees direction d' (its frame) = R d' in the old frame: fetched from there
        src = cam.project(cam.unproject(np.c_[u.ravel(), v.ravel()]) @ R.T).reshape(h, w, 2).astype(np.float32)
        _write(root, name, cv2.remap(img, src[..., 0], src[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT))
    return f"camera turned on its mount by {KNOCK_DEG:g} deg about {np.round(axis, 2).tolist()} after the survey"


def air_calibration(root, roles, cal, rng):
    from bench.camera.io import read_camera_yaml, write_camera_yaml

    cam = read_camera_yaml(cal["camera"])
    K = cam.K.copy()
    K[0, 0] /= N_WATER
    K[1, 1] /= N_WATER
    path = root.parent / "calibrated_air" / "camera.yaml"
    write_camera_yaml(path, cam.replace(K=K, name="FAULT: air calibration"))
    cal["camera"] = path
    return f"camera focal length {cam.K[0, 0]:.1f} -> {K[0, 0]:.1f} px (air calibration)"


def focal_drift(root, roles, cal, rng):
    from bench.camera.io import read_camera_yaml, write_camera_yaml

    cam = read_camera_yaml(cal["camera"])
    K = cam.K.copy()
    sign = float(rng.choice([-1.0, 1.0]))
    K[:2, :2] *= 1 + 0.01 * sign  # the pipeline's file is 1 % off the camera that took the images
    phi = float(rng.uniform(0, 2 * np.pi))
    K[:2, 2] += 3.0 * np.array([np.cos(phi), np.sin(phi)])
    path = root.parent / "calibrated_drift" / "camera.yaml"
    write_camera_yaml(path, cam.replace(K=K, name="FAULT: focal drift"))
    cal["camera"] = path
    return (f"camera file's focal length {cam.K[0, 0]:.1f} -> {K[0, 0]:.1f} px, principal point moved "
            f"{np.linalg.norm(K[:2, 2] - cam.K[:2, 2]):.1f} px (the housing's optics drifted since the lab)")


def fouled_lens(root, roles, cal, rng):
    for name in roles["locate"][:2]:
        img = _read(root, name)
        h, w = img.shape[:2]
        c = (int(rng.uniform(0.25, 0.75) * w), int(rng.uniform(0.25, 0.75) * h))
        r = int(np.sqrt(0.25 * w * h / np.pi))
        mask = np.zeros((h, w), np.uint8)
        cv2.circle(mask, c, r, 255, -1)
        mask = cv2.GaussianBlur(mask, (0, 0), r / 6).astype(float)[..., None] / 255 if img.ndim == 3 else \
            cv2.GaussianBlur(mask, (0, 0), r / 6).astype(float) / 255
        smeared = cv2.GaussianBlur(img, (0, 0), 12) * 0.5 + 40
        _write(root, name, np.clip(img * (1 - mask) + smeared * mask, 0, 255).astype(np.uint8))
    return "smeared, darkened disc over a quarter of both locate images"


def motion_blur(root, roles, cal, rng):
    name = roles["locate"][0]
    n = 21
    angle = float(rng.uniform(0, 180))
    k = np.zeros((n, n), np.float32)
    k[n // 2, :] = 1.0
    k = cv2.warpAffine(k, cv2.getRotationMatrix2D((n / 2 - 0.5, n / 2 - 0.5), angle, 1.0), (n, n))
    _write(root, name, cv2.filter2D(_read(root, name), -1, k / k.sum()))
    return f"{name} blurred over {n} px at {angle:.0f} deg"


def turbid(root, roles, cal, rng):
    from bench.sim.medium import attenuate, water_preset

    medium = water_preset("turbid_harbour")
    for name in roles["locate"][:2]:
        img = _read(root, name)
        rgb = img[..., ::-1] if img.ndim == 3 else np.repeat(img[..., None], 3, axis=2)
        lin = attenuate(rgb.astype(np.float32) / 255, np.full(img.shape[:2], 2.0), medium)
        out = np.clip(lin * 255 + rng.normal(0, 2.0, lin.shape), 0, 255).astype(np.uint8)
        _write(root, name, out[..., ::-1] if img.ndim == 3 else out[..., 1])
    return "both locate images through 2 m more of turbid_harbour water, 2 DN noise"


def new_growth(root, roles, cal, rng):
    for name in roles["locate"][:2]:
        img = _read(root, name)
        h, w = img.shape[:2]
        mask = np.zeros((h, w), np.uint8)
        while mask.mean() / 255 < 0.3:
            c = (int(rng.uniform(0.1, 0.9) * w), int(rng.uniform(0.1, 0.9) * h))
            cv2.ellipse(mask, c, (int(rng.uniform(0.03, 0.12) * w), int(rng.uniform(0.03, 0.12) * h)),
                        float(rng.uniform(0, 180)), 0, 360, 255, -1)
        noise = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 2.0)
        noise = cv2.normalize(noise, None, 30, 200, cv2.NORM_MINMAX)
        growth = np.dstack([noise * 0.6, noise, noise * 0.5]) if img.ndim == 3 else noise
        m = (mask.astype(float) / 255)[..., None] if img.ndim == 3 else mask.astype(float) / 255
        _write(root, name, np.clip(img * (1 - m) + growth * m, 0, 255).astype(np.uint8))
    return "textured growth over ~30 % of both locate images"


FAULTS = {f.__name__: f for f in (clean, swap_images, duplicate_frame, joint_log_shift, joint_offset,
                                  joint_offset_small, mount_bent, mount_knocked, air_calibration, focal_drift,
                                  fouled_lens, motion_blur, turbid, new_growth)}


# --------------------------------------------------------------------------------------------------------- running


def lab_calibration(dataset, out) -> dict:
    """The lab calibration of a rendered in-situ dataset (tracker, rig views; the in_situ kind's defaults)."""
    from bench.scenario.in_situ import Lab, Pipeline, Truth, calibrate_lab

    ds = load_dataset(dataset)
    cfg = {"lab": Lab().model_dump(), "pipeline": Pipeline().model_dump(), "truth": Truth().model_dump()}
    cfg["_file"] = str(ds.root / "manifest.yaml")
    calibrate_lab(ds, ds.robot(), cfg, out)
    return {"camera": Path(out) / "camera.yaml", "robot": Path(out) / "robot.yaml",
            "priors": Path(out) / "calibration_priors.yaml"}


def score(dataset, report, T_world_base) -> dict:
    """True base errors of a localisation (the truth of ``dataset``)."""
    truth = yaml.safe_load((Path(dataset) / "truth" / "truth.yaml").read_text())
    T = invert(np.array(truth["T_world_base_survey"])) @ np.array(truth["T_world_base_locate"])
    if not np.all(np.isfinite(T_world_base)):
        return {"pos_err_mm": float("nan"), "rot_err_deg": float("nan")}
    return dict(zip(("pos_err_mm", "rot_err_deg"), pose_errors(T_world_base, T), strict=True))


def is_silent(row) -> bool:
    """Integrity ok while the true error exceeds the protection levels or :data:`SILENT_MM`."""
    if row["integrity"] != "ok":
        return False
    pr, pa = row["protection_radius_mm"], row["protection_angle_deg"]
    return bool(not row["pos_err_mm"] <= min(pr, SILENT_MM) or not row["rot_err_deg"] <= pa)


def run_faults(dataset, out, faults=None, seed: int = 0, camera=None, robot=None, force: bool = False,
               verbose: bool = True, refine: str = "joints", priors=None, keypoints: str = "sift",
               covariance: str = "white", twin_keypoints: str = "both") -> list:
    """Inject each fault into a copy of ``dataset``, localise, score; writes ``out/faults.csv`` and ``faults.json``.

    Returns the rows (dicts). ``camera`` / ``robot``: the lab calibration's files (default: calibrated here from the
    dataset's rig views and tracker points, with their ``calibration_priors.yaml``). ``refine`` is the estimator
    (:func:`~bench.vision.locate_dataset.locate_dataset`; default ``joints``, the in-situ kind's, under ``priors``:
    the lab's priors file, default the one calibrated here; none when the lab files are given without it);
    ``keypoints`` SIFT's or aligned ones, ``covariance`` the white or the field one (refine ``joints``; both as
    :func:`~bench.vision.locate_dataset.locate_dataset`'s), ``twin_keypoints`` the map's twins
    (:func:`~bench.vision.insitu.twin_map_config`).
    ``out`` is claimed as ``bench faults``' output
    (:func:`bench.fileio.claimed_output_dir`): a foreign folder is refused; ``force`` replaces only an earlier output
    of ``bench faults``.
    """
    dataset = Path(dataset)
    ds = load_dataset(dataset)
    if not (dataset / "truth" / "truth.yaml").is_file():
        raise ConfigError(dataset / "truth" / "truth.yaml", "truth", "fault scoring needs a rendered dataset's truth")
    roles = _site_views(ds)
    names = list(FAULTS) if not faults else list(dict.fromkeys(faults))  # a fault named twice runs once
    for f in names:
        if f not in FAULTS:
            raise ConfigError("--fault", f, f"unknown fault (known: {', '.join(FAULTS)})")
    if refine == "joints":  # what refine 'joints' reads, checked once: else every copy would be 'refused' by it
        from bench.vision.joint_bundle import read_priors
        from bench.vision.locate_dataset import encoder_sigma_rad

        encoder_sigma_rad(dataset)
        if priors is not None:
            read_priors(priors)
    # --out: claimed as bench faults' output before any work (bench.fileio); removed again if the run fails. A re-run
    # with the same dataset and settings writes into it again (the faults asked for replace their rows, the others'
    # stay); other settings are refused without force.
    identity = settings_identity({"dataset": dataset, "camera": camera, "robot": robot, "priors": priors}, seed=seed,
                                 refine=refine, keypoints=keypoints,
                                 **({} if covariance == "white" else {"covariance": covariance}),
                                 **({} if twin_keypoints == "both" else {"twin_keypoints": twin_keypoints}))
    with claimed_output_dir(out, "faults", force=force, identity=identity) as out:
        rows = _run_faults(dataset, out, names, roles, seed, camera, robot, verbose, refine, priors, keypoints,
                           covariance, twin_map_config(twin_keypoints))
    return rows


def _with_earlier_rows(out: Path, rows: list) -> list:
    """``rows`` and the rows of an earlier run into ``out`` (same dataset and settings: its claim) for the faults
    not run again whose folder is still there, in :data:`FAULTS`' order: the table keeps every fault's row."""
    try:
        earlier = json.loads((out / "faults.json").read_text())
    except (OSError, ValueError):
        return rows
    done = {r["fault"] for r in rows}
    # faults.json has null for a non-finite figure: no error (NaN) or no protection level (refused: inf)
    nulls = {"pos_err_mm": float("nan"), "rot_err_deg": float("nan"), "protection_radius_mm": float("inf"),
             "protection_angle_deg": float("inf")}
    kept = [{**r, **{k: v for k, v in nulls.items() if r.get(k) is None}} for r in earlier
            if isinstance(r, dict) and r.get("fault") in FAULTS and r["fault"] not in done
            and (out / r["fault"]).is_dir()]
    order = list(FAULTS)
    return sorted(rows + kept, key=lambda r: order.index(r["fault"]))


def _run_faults(dataset, out, names, roles, seed, camera, robot, verbose, refine, priors, keypoints,
                covariance="white", config=None) -> list:
    from bench.vision.locate_dataset import locate_dataset

    if camera is None or robot is None:
        cal0 = lab_calibration(dataset, out / "calibrated")
        if camera is None and robot is None and priors is None:  # the priors of the lab files they belong to
            priors = cal0["priors"]
        camera, robot = camera or cal0["camera"], robot or cal0["robot"]
    rows = []
    for k, name in enumerate(names):
        work = out / name
        if work.exists():
            shutil.rmtree(work)
        shutil.copytree(dataset, work / "dataset")
        cal = {"camera": Path(camera), "robot": Path(robot)}
        what = FAULTS[name](work / "dataset", roles, cal, np.random.default_rng([seed, k]))
        try:
            res, report = locate_dataset(work / "dataset", work, verbose=False, camera_path=cal["camera"],
                                         robot_path=cal["robot"], seed=seed, refine=refine,
                                         priors_path=priors if refine == "joints" else None, keypoints=keypoints,
                                         covariance=covariance, config=config)
            T = res.T_world_base
        except ConfigError as exc:  # a fault the dataset loader catches is a refusal with its reason
            report = {"integrity": "refused", "integrity_reasons": [str(exc)], "protection_radius_mm": None,
                      "protection_angle_deg": None, "success": False}
            T = np.full((4, 4), np.nan)
        row = {"fault": name, "injected": what, **score(dataset, report, T), "success": bool(report["success"]),
               "integrity": report["integrity"],
               "protection_radius_mm": report["protection_radius_mm"] or float("inf"),
               "protection_angle_deg": report["protection_angle_deg"] or float("inf"),
               "reasons": report["integrity_reasons"]}
        row["silent"] = is_silent(row)
        rows.append(row)
        shutil.rmtree(work / "dataset")  # the images are the input's; the table and locate.json stay
        if verbose:
            print(f"{name:<16} pos {row['pos_err_mm']:9.3f} mm  rot {row['rot_err_deg']:8.4f} deg  "
                  f"{row['integrity']:<8} PR {row['protection_radius_mm']:7.2f} mm {row['protection_angle_deg']:.3f} "
                  f"deg{'  SILENT' if row['silent'] else ''}")
    rows = _with_earlier_rows(out, rows)
    cols = ["fault", "pos_err_mm", "rot_err_deg", "integrity", "protection_radius_mm", "protection_angle_deg",
            "silent", "injected"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    w.writerows([[r[c] for c in cols] for r in rows])
    atomic_write_text(out / "faults.csv", buf.getvalue())
    safe = [{k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items()} for r in rows]
    atomic_write_text(out / "faults.json", json.dumps(safe, indent=2) + "\n")
    if verbose:
        print(f"{sum(r['silent'] for r in rows)} silent failures in {len(rows)} faults; {out / 'faults.csv'}")
    return rows
