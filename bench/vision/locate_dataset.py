"""``bench locate DATASET``: the in-situ pipeline on any dataset folder, real or simulated (section 3.9).

Inputs (the public part of the dataset only): views with roles ``reference``, ``surround`` (the survey, base not
moved) and ``locate`` (two views after the base moved), their joint readings, ``camera.yaml`` (the calibrated
camera) and ``robot.yaml`` with its ``calibration`` section (identified errors and camera mount; without it the
nominal model and an identity mount are used, with a warning). Output: ``locate.json`` in ``out`` (and the
returned :class:`~bench.vision.insitu.LocateResult`): ``T_world_base`` (world = the survey base frame) with its
covariance, position / rotation standard deviations, inliers, condition number, timings, and its integrity
(:mod:`bench.vision.integrity`: ``integrity`` ok / warning / refused, ``integrity_reasons``, ``protection_radius_mm``,
``protection_angle_deg``, ``integrity_tests``). Views with role
``task`` (frames of joint readings taught at the survey parking, e.g. the tool on a valve handle) are re-targeted
from the located base (:func:`bench.robot.task.retarget_taught_pose`): ``locate.json`` then lists the joint readings
to command for each (``tasks``; none when the localisation is refused).

A survey over several **regions** of the scene (the manifest's ``region`` of each posed view: a reference, its
surrounding views and two locate views per region) is mapped and located region by region with the thesis's
estimators, then solved together by the joint bundle (refine ``joints``): one base pose from every region's points,
which pins the base's rotation that one region's narrow view leaves loose. Its integrity
(:func:`~bench.vision.integrity.assess_regions`) tests every region at the common pose; when that is refused, each
subset without one region is solved again, and if exactly one holds the region it leaves out is reported ``left
out`` (a warning). ``locate.json`` then adds ``regions`` (per region: map points, matches, inliers, whether the
solution used it) and ``integrity_regions`` (each one's level).
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.camera.refractive import RefractiveCamera
from bench.dataset import load_dataset
from bench.errors import ConfigError
from bench.fileio import atomic_write_text
from bench.geometry.transforms import invert, rotation_angle, transform_points
from bench.robot.calibration_file import load_calibrated_robot
from bench.robot.orientation import link5_frame
from bench.robot.task import retarget_taught_pose, taught_pose
from bench.vision.features import detect_sift
from bench.vision.insitu import TWIN_WORTH, LocateResult, MapConfig, ViewObservation, build_map, locate, locate_pnp
from bench.vision.integrity import (
    KAPPA_UNMEASURED,
    MIN_INLIERS,
    LabPrior,
    assess,
    kappa_of,
    point_protection_radius,
    relevel,
)
from bench.vision.tilt import VEHICLE_FILE, read_vehicle_yaml
from bench.vision.tilt import check as check_tilt
from bench.vision.tilt import fuse as fuse_tilt


def observe(view, camera, robot, eps, T_link5_cam, max_features: int = 0, features_fn=None) -> ViewObservation:
    """Detect SIFT in a dataset view, normalise its keypoints, and pose it through the calibrated kinematics.

    ``features_fn(view) -> Features`` replaces the SIFT detector (e.g. an evaluator's ideal features); default SIFT.
    """
    q = robot.check_q(view.q, f"joints.csv ({view.name})")
    if np.any(q < robot.q_min - 1e-9) or np.any(q > robot.q_max + 1e-9):
        raise ConfigError("joints.csv", view.name, "joint readings outside the joint limits")
    if features_fn is None:
        f = detect_sift(view.image(expected_size=camera.size), max_features=max_features, channel_order="rgb")
    else:
        f = features_fn(view)
    f, x_n = normalised(f, camera)
    return ViewObservation(view.name, f, x_n, link5_frame(robot, q, eps) @ T_link5_cam)


def normalised(f, camera, depth=None) -> tuple:
    """``(features, x_n)``: the keypoints' ideal normalised coordinates through ``camera``, without the keypoints
    where its distortion cannot be inverted (beyond a k3 model's fold: they would be NaN rays). A refractive camera
    (:class:`~bench.camera.refractive.RefractiveCamera`) gives the lens-centre pinhole coordinates of each pixel's
    water ray at ``depth`` (m, per keypoint; default its working range)."""
    if not len(f):
        return f, np.empty((0, 2))
    x_n = camera.normalised(f.uv, depth) if isinstance(camera, RefractiveCamera) else camera.undistort_pixels(f.uv)
    ok = np.all(np.isfinite(x_n), axis=1)
    return (f, x_n) if ok.all() else (f.subset(np.flatnonzero(ok)), x_n[ok])


#: a refractive camera's solve passes at most (the first at the working range, then at the solution's depths; each
#: shrinks the depths' effect ~100x: measured 0.015 / 1.6e-4 / 8e-7 mm after 2 / 3 / 4 passes on exact data) and the
#: change of the base pose, as a fraction of its standard deviation, below which it stops
REFRACTIVE_PASSES = 6
SETTLED_FRACTION = 1e-3
#: a keypoint within this many pixels (at the paraxial focal length) of a map point's image takes its depth
SAME_POINT_PX = 1.5
#: otherwise the median depth of this many nearest map points in the image
DEPTH_NEIGHBOURS = 5
#: the keypoint error field's order of ``covariance: field`` (cubic: the bound's, docs/bounds.md)
FIELD_ORDER = 3


def keypoint_depths(x_n, p_cam, focal_px) -> np.ndarray:
    """Depths (N,) (m) for keypoints at normalised coordinates ``x_n (N, 2)`` from points ``p_cam (M, 3)`` in the
    same camera's frame: a keypoint on a point's image (within :data:`SAME_POINT_PX`) takes that point's depth,
    the others the median depth of the :data:`DEPTH_NEIGHBOURS` nearest points in the image (the scene's depth
    around them). NaN when no point lies in front of the camera."""
    from scipy.spatial import cKDTree

    p = np.asarray(p_cam, float)
    p = p[np.all(np.isfinite(p), axis=1) & (p[:, 2] > 0)]
    if not len(p) or not len(x_n):
        return np.full(len(x_n), np.nan)
    tree = cKDTree(p[:, :2] / p[:, 2:3])
    k = min(DEPTH_NEIGHBOURS, len(p))
    dist, idx = tree.query(x_n, k=k)
    dist, idx = dist.reshape(len(x_n), k), idx.reshape(len(x_n), k)
    z = np.median(p[idx, 2], axis=1)
    same = dist[:, 0] <= SAME_POINT_PX / focal_px
    z[same] = p[idx[same, 0], 2]
    return z


def _refract_again(obs, camera, maps, res, regions) -> dict:
    """The observations with every keypoint's coordinates recomputed at the depth the first solution gives it
    (:func:`keypoint_depths` from the map points of its region (``maps``, one per entry of ``regions``) in each
    view: the survey views through their kinematics, the locate views through the located base); a view without
    depths keeps its coordinates."""

    out = {}
    for kmap, (_, roles) in zip(maps, regions, strict=True):
        X_site = transform_points(kmap.T_world_ref, kmap.p_ref)
        for r, views in roles.items():
            for v in views:
                o = obs[v.name]
                T_site_cam = o.T_base_cam if r != "locate" else res.T_world_base @ o.T_base_cam
                z = keypoint_depths(o.x_n, transform_points(invert(T_site_cam), X_site), camera.fx)
                if not np.all(np.isfinite(z)):
                    out[v.name] = o
                    continue
                f, x_n = normalised(o.features, camera, z)
                out[v.name] = replace(o, features=f, x_n=x_n)
    return out


def _retarget_tasks(ds, robot, eps, T_site_base, q_now, covariance, tests) -> dict:
    """Joint readings to command for every taught ``task`` frame, from the located base (see the module docstring),
    and the tool tip's protection radius there (:func:`~bench.vision.integrity.point_protection_radius`, from the
    base ``covariance`` and the integrity ``tests``)."""
    out = {}
    for v in [v for v in ds.views if v.role == "task"]:
        if v.q is None:
            raise ConfigError(ds.root / "joints.csv", v.name, "a task frame needs joint readings")
        q_taught = robot.check_q(v.q, f"joints.csv ({v.name})")
        r = retarget_taught_pose(robot, eps, q_taught, T_site_base, q_seed=q_now)
        p_site = transform_points(taught_pose(robot, eps, q_taught), robot.p_ee)  # the taught tool tip
        pr = point_protection_radius(covariance, tests, T_site_base, p_site)
        out[v.name] = {"success": bool(r.success), "message": r.message,
                       "q_command_deg": np.rad2deg(r.solutions[0]).tolist(),
                       "position_error_mm": float(r.position_error_m * 1e3),
                       "protection_radius_mm": float(pr * 1e3) if np.isfinite(pr) else None}
    return out


#: the encoders' specification in a dataset (noise_deg, resolution_deg: the joint-readings' datasheet)
ENCODERS_FILE = "encoders.yaml"


def encoder_sigma_rad(root) -> float:
    """The encoders' standard deviation per joint (rad) from the dataset's ``encoders.yaml`` specification:
    ``sqrt(noise^2 + resolution^2 / 12)`` (noise and uniform quantisation); a missing file or a bad value is a
    one-line error naming the file and key."""
    from bench.fileio import read_yaml

    path = Path(root) / ENCODERS_FILE
    spec = read_yaml(path, missing="missing: refine 'joints' needs the encoders' specification (noise_deg, "
                                   "resolution_deg)") or {}
    vals = {}
    for key in ("noise_deg", "resolution_deg"):
        v = spec.get(key) if isinstance(spec, dict) else None
        if not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0 or v > 5:
            raise ConfigError(path, key, f"expected a number of degrees in [0, 5], got {v!r}")
        vals[key] = np.deg2rad(float(v))
    sigma = float(np.sqrt(vals["noise_deg"] ** 2 + vals["resolution_deg"] ** 2 / 12))
    if sigma <= 0:
        raise ConfigError(path, "noise_deg", "noise and resolution are both 0: the readings would be exact; use "
                                             "refine 'bundle'")
    return sigma


def _guided_used(kmap, view_a, view_b, used, T_ref_a, T_ref_b, K, dist, camera) -> tuple:
    """``used`` (map indices, their keypoints in views a and b) grown by guided matching
    (:mod:`bench.vision.guided`) in both locate views, at the poses ``T_ref_a``, ``T_ref_b`` through the camera
    ``K``, ``dist`` (as the joint bundle refined them). The keypoints are compared in the joint bundle's pixels:
    their normalised coordinates through ``camera`` (the pixel camera the bundle started from; for a refractive
    camera its virtual pinhole, whose pixels are not the detected ones). Per view, the verified matches set the
    search: the radius is :data:`~bench.vision.guided.RADIUS_FACTOR` x the 90th percentile of their distances from
    their projections (the map points' own errors). No descriptor-distance gate: on the envelope's 150
    availability-cell runs one at the verified matches' 95th percentile (or their maximum) let a badly conditioned
    0.5 m run reach 23 mm, which without it stays at 7 mm; the ratio test within the window and the joint bundle's
    gate decide. Returns ``((indices, x_a, x_b), radii)``: the map points found in both views added to
    ``used`` (the verified ones keep their keypoints), and the two radii (px). A point found in one view only is not
    added: measured on six envelope runs, such points lowered the protection radius but doubled the error on two."""
    from bench.camera.model import distort, project_pinhole, to_pixels
    from bench.vision.guided import RADIUS_FACTOR, RATIO, search_by_projection

    idx = np.asarray(used[0], int)
    found, radii = [], []
    for view, x_used, T in ((view_a, used[1], T_ref_a), (view_b, used[2], T_ref_b)):
        x_n = np.asarray(view.x_n)
        where = {tuple(x): i for i, x in enumerate(x_n)}  # SIFT's twins (one position, two orientations): either
        iv = np.array([where[tuple(x)] for x in np.asarray(x_used)], int)
        uv_view = to_pixels(distort(x_n, camera.dist), camera.K)  # the joint bundle's pixels of the keypoints
        uv_proj = to_pixels(distort(project_pinhole(transform_points(invert(T), kmap.p_ref)), dist), K)
        off = np.linalg.norm(uv_proj[idx] - uv_view[iv], axis=1)
        r = max(RADIUS_FACTOR * float(np.nanquantile(off, 0.9)), 1.0)
        i_m, i_v = search_by_projection(uv_proj, uv_view, kmap.features.descriptors, view.features.descriptors, r,
                                        RATIO)
        found.append(dict(zip(i_m.tolist(), i_v.tolist(), strict=True)))
        radii.append(r)
    verified = {int(i): k for k, i in enumerate(idx)}
    both = sorted(set(verified) | (set(found[0]) & set(found[1])))
    x_a = np.array([used[1][verified[i]] if i in verified else view_a.x_n[found[0][i]] for i in both]).reshape(-1, 2)
    x_b = np.array([used[2][verified[i]] if i in verified else view_b.x_n[found[1][i]] for i in both]).reshape(-1, 2)
    return (np.array(both, int), x_a, x_b), radii


def _align_keypoints(obs, regions, camera, config) -> tuple:
    """The observations with every keypoint matched to its region's reference keypoint moved onto the reference's
    image patch (:func:`bench.vision.patch_align.align_to_reference`), re-normalised through ``camera``; the reference
    views keep SIFT's keypoints (the anchors). Returns ``(obs, stats)``: ``keypoints_matched`` (view keypoints matched
    to a reference keypoint), ``keypoints_aligned`` and ``keypoint_shift_median_px`` (the aligned keypoints' median
    move)."""
    from bench.vision.insitu import view_matches
    from bench.vision.patch_align import align_to_reference, grey

    cfg = config or MapConfig()
    out, matched, shifts = dict(obs), 0, [np.empty(0)]
    for _, roles in regions:
        ref = roles["reference"][0]
        views = {v.name: (grey(v.image(expected_size=camera.size)), obs[v.name].features)
                 for v in roles["surround"] + roles["locate"]}
        feats, n, shift = align_to_reference(grey(ref.image(expected_size=camera.size)), obs[ref.name].features,
                                             views, lambda a, b: view_matches(a, b, cfg))
        for name, f in feats.items():
            f, x_n = normalised(f, camera)
            out[name] = replace(obs[name], features=f, x_n=x_n)
        matched, shifts = matched + n, [*shifts, shift]
    shift = np.concatenate(shifts)
    return out, {"keypoints_matched": matched, "keypoints_aligned": len(shift),
                 "keypoint_shift_median_px": float(np.median(shift)) if len(shift) else float("nan")}


def _refine_joints(res, parts, obs, robot, eps, T_link5_cam, camera, sigma_enc, priors=None, guided: bool = False,
                   loss: str | None = None, map_points: str = "all", field_order: int | None = None,
                   one_keypoint_px: float = 0.0):
    """The thesis estimator's pose refined by :func:`~bench.vision.joint_bundle.joint_bundle` (joints under the
    encoder prior); on failure the thesis estimate is kept and the message says why.

    ``parts``: one ``(kmap, roles, used)`` per region of the scene - its map, its views by role and the map points
    its two locate views used (a :class:`~bench.vision.insitu.LocateResult`'s ``used``); several regions are solved
    together: one base pose, every view's joints, the shared camera, every region's points. ``res``: the thesis
    estimate to start from. With ``guided`` each region's map is then searched again in its locate views at the
    refined poses and camera (:mod:`bench.vision.guided`) and the joint bundle re-run on the grown sets; ``loss``:
    the joint bundle's (``joint_bundle``); ``map_points``: which map points it weighs
    (:func:`~bench.vision.joint_bundle.observations_of`); ``one_keypoint_px`` > 0: a view's observations within it
    of each other are one keypoint, weighed as :data:`~bench.vision.insitu.TWIN_WORTH` measurements
    (:func:`~bench.vision.joint_bundle.detection_weights`; 0: each observation one); ``field_order``: the
    covariance with each view's keypoint error field of that order (:mod:`bench.vision.field_covariance`), None:
    white. Returns ``(result, refined, used)``: ``refined`` False when the thesis's estimate (and covariance) is what
    comes back; ``used`` the points of every region the returned estimate used (the result's own ``used`` is the
    first region's)."""
    from bench.camera.model import distort, to_pixels
    from bench.vision.integrity import pose_condition
    from bench.vision.joint_bundle import detection_weights, joint_bundle, observations_of

    useds = [u for _, _, u in parts]
    if any(u is None or len(u[0]) < 3 for u in useds):
        return replace(res, message=res.message + "; joint bundle skipped (fewer than 3 points)"), False, useds
    t0 = time.perf_counter()
    views = [v for _, roles, _ in parts for r in ("reference", "surround", "locate") for v in roles[r]]
    q_read = np.array([v.q for v in views], dtype=float)
    is_loc = np.array([v.role == "locate" for v in views])
    first = np.cumsum([0] + [1 + len(roles["surround"]) + 2 for _, roles, _ in parts])  # each region's first view

    def bundle(useds, T_start):
        view, point, uv, X = [], [], [], []
        for (kmap, roles, _), used, v0 in zip(parts, useds, first, strict=False):
            vw, pt, x, idx = observations_of(kmap, used, len(roles["surround"]), map_points)
            view.append(vw + v0)
            point.append(pt + sum(len(p) for p in X))
            uv.append(to_pixels(distort(x, camera.dist), camera.K))  # the keypoints as detected (x: undistorted)
            X.append(transform_points(kmap.T_world_ref, kmap.p_ref[idx]))
        X, view, uv = np.concatenate(X), np.concatenate(view), np.concatenate(uv)
        w = detection_weights(view, uv, one_keypoint_px, TWIN_WORTH) if one_keypoint_px > 0 else None
        return joint_bundle(robot, eps, T_link5_cam, q_read, is_loc, T_start, view, np.concatenate(point), uv, X,
                            sigma_enc, 0.1, camera.K, camera.dist, **(priors or {}), loss=loss,
                            field_order=field_order, image_size=camera.size, weights=w), X  # 0.1 px: a start

    try:
        jb, X = bundle(useds, res.T_world_base)
    except (ValueError, np.linalg.LinAlgError) as exc:
        return replace(res, message=f"{res.message}; joint bundle skipped ({exc})"), False, useds
    res.timings_s["joint_bundle_s"] = time.perf_counter() - t0
    if not jb.success:
        return replace(res, message=f"{res.message}; joint bundle skipped ({jb.message})"), False, useds
    if jb.sigma_px < 1e-6:  # exact data (an evaluator's oracle): nothing to weigh, the thesis estimate is exact too
        return replace(res, message=f"{res.message}; joint bundle: residuals {jb.sigma_px:.2g} px, estimate "
                                    f"kept"), False, useds
    note = ""
    if guided:
        t1 = time.perf_counter()
        mount = T_link5_cam if jb.T_link5_cam is None else jb.T_link5_cam
        K = camera.K if jb.K is None else jb.K
        dist = camera.dist if jb.dist is None else jb.dist
        grown, radii = [], []
        for (kmap, roles, used), v0 in zip(parts, first, strict=False):
            T_ref_site = invert(kmap.T_world_ref) @ jb.T_site_base
            a, b = (obs[v.name] for v in roles["locate"][:2])
            k = v0 + 1 + len(roles["surround"])  # the region's first locate view
            T_ref = [T_ref_site @ link5_frame(robot, jb.q[k + i], eps) @ mount for i in (0, 1)]
            g, r = _guided_used(kmap, a, b, used, T_ref[0], T_ref[1], K, dist, camera)
            grown.append(g)
            radii += r
        n_grown, n_used = sum(len(g[0]) for g in grown), sum(len(u[0]) for u in useds)
        note = (f"; guided matching (radius {' / '.join(f'{r:.1f}' for r in radii)} px): {n_grown} map points in "
                f"both locate views (verified {n_used})")
        if n_grown > n_used:
            try:
                jb2, X2 = bundle(grown, jb.T_site_base)
            except (ValueError, np.linalg.LinAlgError) as exc:
                jb2, note = None, f"{note}, bundle skipped ({exc})"
            if jb2 is not None and not jb2.success:
                note = f"{note}, bundle skipped ({jb2.message})"
            elif jb2 is not None:
                jb, useds, X = jb2, grown, X2
        res.timings_s["guided_s"] = time.perf_counter() - t1
    kmap, roles, _ = parts[0]
    T_ref_a = invert(kmap.T_world_ref) @ jb.T_site_base @ obs[roles["locate"][0].name].T_base_cam
    # test 6 then weighs the geometry of the pose the joint bundle solved, not the condition of the start's system
    cond = pose_condition(jb.covariance, jb.T_site_base, X)
    return replace(res, message=f"{res.message}; {jb.message[4:]}{note}", T_world_base=jb.T_site_base,
                   T_ref_cam=T_ref_a, covariance=jb.covariance, pose_condition=cond, used=useds[0],
                   field=None if jb.field is None else jb.field.report()), True, useds


def _regions(ds, pnp: bool, refine: str) -> list:
    """``[(region, roles)]``: the in-situ views of every region of the scene (the manifest's ``region``, in the
    order of their first view); ``roles`` maps ``reference``, ``surround`` and ``locate`` to the region's views (its
    locate views cut to the two the solve takes, one for PnP). A region needs one reference view, a surrounding view
    and its locate views; several regions are solved together by the joint bundle, so they need refine 'joints'
    with two locate views each. A missing piece is a one-line error naming the region."""
    where = ds.root / "manifest.yaml"
    posed = [v for v in ds.views if v.role in ("reference", "surround", "locate")]
    names = list(dict.fromkeys(v.region for v in posed)) or [""]
    if len(names) > 1 and (pnp or refine != "joints"):
        raise ConfigError(where, "views", f"{len(names)} regions ({', '.join(map(repr, names))}) are solved together "
                                          f"by refine 'joints' from two locate views each (got refine {refine!r}"
                                          f"{' and PnP' if pnp else ''})")
    out = []
    for name in names:
        roles = {r: [v for v in posed if v.role == r and v.region == name] for r in ("reference", "surround",
                                                                                       "locate")}
        of = f" in region {name!r}" if len(names) > 1 else ""
        if len(roles["reference"]) != 1:
            raise ConfigError(where, "views", f"expected one view with role 'reference'{of}, found "
                                              f"{len(roles['reference'])}")
        if not roles["surround"]:
            raise ConfigError(where, "views", f"no view with role 'surround' (the survey){of}")
        if len(roles["locate"]) < (1 if pnp else 2):
            raise ConfigError(where, "views", f"expected {1 if pnp else 2} views with role 'locate'{of}, found "
                                              f"{len(roles['locate'])}")
        roles["locate"] = roles["locate"][: 1 if pnp else 2]
        out.append((name, roles))
    return out


def _combine(per, include, maps, regions, obs, refine, robot, eps, T_link5_cam, camera, sigma_enc, priors, guided,
             loss, map_points, field_order=None, one_keypoint_px: float = 0.0) -> tuple:
    """The estimate of the regions ``include`` (indices) from their thesis estimates ``per``: with one region its
    own, refined by the joint bundle with refine 'joints'; with several the joint bundle over all of them together,
    started from the region with the most inliers (which then comes first in ``include``; regions whose thesis
    estimator found no pose, or one on fewer than :data:`~bench.vision.integrity.MIN_INLIERS` inliers, are left
    out). Returns ``(include, result, refined, thesis, used)`` (see
    :func:`_refine_joints`; ``thesis`` the start's thesis estimate)."""
    if len(regions) == 1:
        res = per[0]
        if sigma_enc is None or not res.success:  # refine 'joints' and two views: sigma_enc is given
            return [0], res, False, None, [res.used]
        out, refined, used = _refine_joints(res, [(maps[0], regions[0][1], res.used)], obs, robot, eps, T_link5_cam,
                                            camera, sigma_enc, priors, guided, loss, map_points, field_order,
                                            one_keypoint_px)
        return [0], out, refined, res, used
    # a region with fewer inliers than test 5 accepts has too little to add (not a fault: left out like a failure)
    include = [i for i in include if per[i].success and per[i].used is not None and len(per[i].used[0]) >= 3
               and per[i].n_inliers >= MIN_INLIERS]
    if not include:
        nan = np.full((4, 4), np.nan)
        why = "; ".join(f"region {name!r}: {r.message}" for (name, _), r in zip(regions, per, strict=True))
        return [], LocateResult(False, f"no region localised ({why})", nan, nan, np.full((6, 6), np.nan), np.nan,
                                sum(r.n_matches for r in per), 0), False, None, []
    start = max(include, key=lambda i: per[i].n_inliers)
    include = [start] + [i for i in include if i != start]
    names = ", ".join(f"{regions[i][0]!r} ({per[i].n_inliers} inliers)" for i in include)
    res = replace(per[start], message=f"regions {names}; start: region {regions[start][0]!r}: {per[start].message}",
                  n_matches=sum(per[i].n_matches for i in include), n_inliers=sum(per[i].n_inliers for i in include),
                  timings_s=dict(per[start].timings_s))
    out, refined, used = _refine_joints(res, [(maps[i], regions[i][1], per[i].used) for i in include], obs, robot,
                                        eps, T_link5_cam, camera, sigma_enc, priors, guided, loss, map_points,
                                        field_order, one_keypoint_px)
    return include, out, refined, per[start], used


def _assess_regions(res, per, include, maps, regions, obs, camera, config, seed, lab):
    """:func:`~bench.vision.integrity.assess_regions` of the regions ``include`` at the common result ``res``."""
    from bench.vision.integrity import assess_regions

    parts = []
    for i in include:
        name, roles = regions[i]
        parts.append((name, maps[i], [obs[v.name] for v in roles["surround"]], obs[roles["locate"][0].name],
                      obs[roles["locate"][1].name], per[i]))
    return assess_regions(parts, res, camera.fx, camera.size, config, seed, lab)


def locate_dataset(root, out=None, method: str = "svd", pnp: bool = False, config: MapConfig | None = None,
                   seed: int = 0, verbose: bool = True, camera_path=None, robot_path=None, refine="bundle",
                   ransac: dict | None = None, details: dict | None = None, features_fn=None, priors_path=None,
                   guided: bool = False, loss: str | None = None, map_points: str = "all", keypoints: str = "sift",
                   ins_tilt: str = "fuse", refine_k3: bool = False, covariance: str = "white"):
    """Build the map from the survey views and locate the base from the two ``locate`` views.

    ``camera_path`` / ``robot_path`` replace the dataset's own files (e.g. the results of an earlier calibration);
    ``ransac`` passes ``iterations``, ``d_r`` (m), ``r_lim`` to :func:`~bench.vision.insitu.locate`. ``refine``:
    ``none`` / ``pose`` / ``bundle`` (the thesis's estimators and refinements: :func:`~bench.vision.insitu.locate`)
    or ``joints`` (``bundle``, then every view's joints refined under the encoder prior of the dataset's
    ``encoders.yaml``: :mod:`bench.vision.joint_bundle`; with ``priors_path``, a ``calibration_priors.yaml`` of
    the lab's covariances, also the intrinsics and the mount under them). A ``details``
    dict, if given, receives the intermediate objects (``map``, ``observations``, ``camera``, ``robot``, ``eps``,
    ``T_link5_cam``; with ``joints`` also ``thesis_result``, the ``bundle`` estimate before the joints)
    for inspection and visualisation. ``features_fn`` replaces the SIFT detector (see
    :func:`observe`). ``loss`` (``refine: joints``): the joint bundle's, None (least squares) or ``"huber"``;
    ``map_points`` (``refine: joints``): ``"all"`` (every map point; those the locate views do not see hold the
    survey's joints and the shared camera) or ``"located"`` (only the points both locate views matched).
    ``keypoints``: ``"sift"`` (SIFT's keypoints, the thesis's) or ``"aligned"`` (every keypoint matched to its
    region's reference keypoint moved onto the reference's image patch: :func:`_align_keypoints`; not with
    ``features_fn``, whose keypoints are an oracle's).
    ``ins_tilt`` (a dataset with the vehicle's ``vehicle.yaml``): ``"fuse"`` (test 7 on the images' pose, then the
    INS's tilt fused into the pose and its covariance, and the protection levels again: :func:`bench.vision.tilt.fuse`)
    or ``"check"`` (test 7 only; the images' pose is returned). The report keeps the images' pose beside the fused
    one (``T_world_base_vision``). ``covariance`` (``refine: joints``): ``"white"`` (the joint bundle's
    first-order covariance of independent pixel noise) or ``"field"`` (the estimate's covariance with each view's
    keypoint error field to cubic order, measured on the bundle's residuals: :mod:`bench.vision.field_covariance`).
    Returns ``(LocateResult, report dict)``; writes ``out/locate.json`` when ``out`` is given.
    """
    t0 = time.perf_counter()
    if map_points not in ("all", "located"):
        raise ConfigError("locate_dataset", "map_points", f"expected 'all' or 'located', got {map_points!r}")
    if keypoints not in ("sift", "aligned"):
        raise ConfigError("locate_dataset", "keypoints", f"expected 'sift' or 'aligned', got {keypoints!r}")
    if covariance not in ("white", "field"):
        raise ConfigError("locate_dataset", "covariance", f"expected 'white' or 'field', got {covariance!r}")
    one_keypoint_px = (config or MapConfig()).one_keypoint_px  # SIFT's twins weighed (pipeline.twin_keypoints)
    if covariance == "field" and one_keypoint_px > 0:
        raise ConfigError("locate_dataset", "covariance", "the keypoint-field covariance weighs every observation as "
                          "one measurement: not with twin keypoints 'weighted'")
    if ins_tilt not in ("fuse", "check"):
        raise ConfigError("locate_dataset", "ins_tilt", f"expected 'fuse' or 'check', got {ins_tilt!r}")
    ds = load_dataset(root)
    camera_path = Path(camera_path) if camera_path else ds.camera_path
    robot_path = Path(robot_path) if robot_path else ds.robot_path
    if camera_path is None or robot_path is None:
        raise ConfigError(Path(root) / "manifest.yaml", "camera/robot", "the dataset needs camera.yaml and robot.yaml")
    from bench.camera.io import read_camera_yaml

    camera = read_camera_yaml(camera_path, allow_refractive=True)
    robot, eps, T_link5_cam = load_calibrated_robot(robot_path)
    if T_link5_cam is None:
        warnings.warn(f"{robot_path}: no calibration.camera_mount; using an identity mount", stacklevel=2)
        T_link5_cam = np.eye(4)
    regions = _regions(ds, pnp, refine)
    sigma_enc = encoder_sigma_rad(ds.root) if refine == "joints" and not pnp else None  # checked before the work
    tilt = read_vehicle_yaml(ds.root / VEHICLE_FILE) if (ds.root / VEHICLE_FILE).is_file() else None  # test 7
    priors = None
    if priors_path is not None and refine == "joints" and not pnp:
        from bench.vision.joint_bundle import K3_PRIOR_SD, lab_blocks, lab_prior, read_priors

        priors = read_priors(priors_path)
        if refine_k3 and priors["k3_sd"] is None:  # the file's own sd or the lab's own k3 block, else a wide one
            if priors["cov_dist"] is None:
                raise ConfigError(priors_path, "distortion_covariance", "missing: refining k3 needs the lens's "
                                                                        "k1 k2 p1 p2 block")
            if len(priors["cov_dist"]) == 4:
                priors["k3_sd"] = K3_PRIOR_SD
    obs = {v.name: observe(v, camera, robot, eps, T_link5_cam, features_fn=features_fn)
           for _, roles in regions for r in roles.values() for v in r}
    t_detect = time.perf_counter() - t0
    aligned = keypoints == "aligned" and features_fn is None  # an oracle's features are where they belong
    align_stats, timing = {}, {}
    if aligned:
        obs, align_stats = _align_keypoints(obs, regions, camera, config)
        timing["keypoint_align_s"] = time.perf_counter() - t0 - t_detect
    # the joint bundle works in pixels: a refractive camera's coordinates go to it through its virtual pinhole
    pixels_camera = camera.virtual_camera() if isinstance(camera, RefractiveCamera) else camera
    lab = None if priors is None else LabPrior(  # test 2
        lab_prior(**lab_blocks(priors)), pixels_camera.K, pixels_camera.dist,
        refractive=camera if isinstance(camera, RefractiveCamera) else None)

    def combine(per, maps, obs, include):
        """:func:`_combine` of the regions ``include`` with this call's robot, camera and settings."""
        return _combine(per, include, maps, regions, obs, refine, robot, eps, T_link5_cam, pixels_camera, sigma_enc,
                        priors, guided, loss, map_points, FIELD_ORDER if covariance == "field" else None,
                        one_keypoint_px)

    def solve(obs):
        """Every region's map and thesis estimate, then their estimate together (:func:`_combine`: the joint
        bundle's with refine 'joints')."""
        t = time.perf_counter()
        maps = [build_map(obs[roles["reference"][0].name], [obs[v.name] for v in roles["surround"]], config)
                for _, roles in regions]
        t_map = time.perf_counter() - t
        per = []  # the thesis estimator's result in each region
        for kmap, (_, roles) in zip(maps, regions, strict=True):
            a = obs[roles["locate"][0].name]
            per.append(locate_pnp(kmap, a, config, focal_px=camera.fx) if pnp else
                       locate(kmap, a, obs[roles["locate"][1].name], config, method=method, rng=seed,
                              refine="bundle" if refine == "joints" else refine, focal_px=camera.fx,
                              **(ransac or {})))  # focal: the baseline checks' 1 px (Eq. 123, 199)
        return (maps, per, *combine(per, maps, obs, range(len(per))), t_map)

    maps, per, include, res, refined, thesis, useds, t_map = solve(obs)
    passes = 1
    while isinstance(camera, RefractiveCamera) and res.success and passes < REFRACTIVE_PASSES:
        # the port: each keypoint again at the depth the last solution gives it, and the solve again, until the
        # base pose settles (each pass shrinks the depths' effect by ~ the rays' offset / range, ~1e-2)
        obs2 = _refract_again(obs, camera, maps, res, regions)
        solved2 = solve(obs2)
        t_map, passes = t_map + solved2[-1], passes + 1
        res2 = solved2[3]
        if not res2.success:  # the last pass's result stands
            res = replace(res, message=f"{res.message}; refractive pass {passes} failed: {res2.message}")
            passes -= 1
            break
        D = np.linalg.inv(res.T_world_base) @ res2.T_world_base
        obs, (maps, per, include, res, refined, thesis, useds) = obs2, solved2[:-1]
        std = (np.full(6, 1e-6) if res.covariance is None else  # no covariance: settle at 1 nm / 1 nrad
               np.sqrt(np.clip(np.diag(np.asarray(res.covariance, float)), 0.0, None)))
        if (np.linalg.norm(D[:3, 3]) <= SETTLED_FRACTION * np.linalg.norm(std[3:])
                and rotation_angle(D[:3, :3]) <= SETTLED_FRACTION * np.linalg.norm(std[:3])):
            break
    if isinstance(camera, RefractiveCamera):
        res = replace(res, message=f"{res.message}; refractive camera: {passes} pass(es)")

    def calibrated(res, refined, n_regions):
        """The estimator's first-order covariance, calibrated by its measured optimism
        (:data:`~bench.vision.integrity.KAPPA`) - of the estimate returned: 'joints' falls back to the thesis's
        'bundle' when the joint bundle fails or is skipped; 'joints' was measured with the lab priors (without them
        it is unmeasured), over one region and over several (``n_regions`` solved together), on SIFT's keypoints or
        aligned ones, with SIFT's twins weighed or not. Returns ``(result, kappa)``."""
        used = ("joints" if refined else "bundle") if refine == "joints" else refine
        twins = "weighted" if used == "joints" and one_keypoint_px > 0 else "both"
        kappa = (kappa_of(used, pnp, n_regions, "aligned" if aligned else "sift",
                          covariance if used == "joints" else "white", twins)
                 if used != "joints" or priors is not None else KAPPA_UNMEASURED)
        return (replace(res, covariance=kappa**2 * np.asarray(res.covariance, float)) if res.success else res), kappa

    res, kappa = calibrated(res, refined, len(include))
    t_int = time.perf_counter()
    if len(regions) == 1:
        _, roles = regions[0]
        integ = assess(maps[0], [obs[v.name] for v in roles["surround"]], obs[roles["locate"][0].name],
                       None if pnp else obs[roles["locate"][1].name], res, camera.fx, camera.size, config, seed, lab)
    else:
        integ = _assess_regions(res, per, include, maps, regions, obs, camera, config, seed, lab)
        if res.success and integ.level == "refused" and len(include) > 1:
            # fault exclusion (one faulty region at a time): every subset without one region solved again; when
            # exactly one of them holds, the region it leaves out is the faulty one. The result is then at best a
            # warning (a fault was found; another may hide in the regions kept). None or several: refused.
            held = []
            for k in include:
                again = combine(per, maps, obs, [i for i in include if i != k])
                res2, kappa2 = calibrated(again[1], again[2], len(again[0]))
                integ2 = _assess_regions(res2, per, again[0], maps, regions, obs, camera, config, seed, lab)
                if res2.success and integ2.level != "refused":
                    held.append((k, again, res2, kappa2, integ2))
            if len(held) == 1:
                k, again, res2, kappa2, integ2 = held[0]
                name = regions[k][0]
                why = integ.region_reasons.get(name) or integ.reasons
                integ2.reasons.insert(0, f"region {name} left out: {'; '.join(why)}")
                integ2.level, integ2.regions[name] = "warning", "left out"
                (include, _, refined, thesis, useds), res, kappa, integ = again, res2, kappa2, integ2
            elif len(held) > 1:
                integ.reasons.append(f"leaving out any one of regions {', '.join(regions[h[0]][0] for h in held)} "
                                     "gives a pose that holds: the faulty one is not known")
        for name, _ in regions:  # a region the thesis estimator found no pose in adds nothing (its message says why)
            integ.regions.setdefault(name, "not localised")
    T_vision, fused = res.T_world_base, None
    if tilt is not None and res.success:  # test 7: the located base's tilt against the vehicle's INS
        integ = check_tilt(integ, res.T_world_base, res.covariance, tilt)
        if ins_tilt == "fuse" and integ.level != "refused":  # test 7 was the update's innovation test
            T, C, fused = fuse_tilt(res.T_world_base, res.covariance, tilt, integ.tests.get("inflation_chi2", 1.0))
            kmap0 = maps[include[0] if include else 0]
            D = T @ invert(res.T_world_base)  # locate view a moves with the base
            res = replace(res, T_world_base=T, covariance=C, T_ref_cam=invert(kmap0.T_world_ref) @ D
                          @ kmap0.T_world_ref @ res.T_ref_cam, message=f"{res.message}; the INS's tilt fused")
            integ = relevel(integ, C)
    if details is not None and thesis is not None:
        details["thesis_result"] = thesis
    res.timings_s.update({"detect_s": t_detect, **timing, "map_s": t_map, "integrity_s": time.perf_counter() - t_int,
                          "pipeline_total_s": time.perf_counter() - t0})
    kmap, roles = maps[include[0] if include else 0], regions[include[0] if include else 0][1]
    if details is not None:
        details.update(map=kmap, observations=obs, camera=camera, robot=robot, eps=eps, T_link5_cam=T_link5_cam,
                       integrity=integ, maps=maps, regions=regions, region_results=per, region_used=useds,
                       regions_solved=include)
    report = {"dataset": str(ds.root), "success": res.success, "message": res.message,
              "map_points": sum(len(m) for m in maps), "map_stats": kmap.stats, "n_matches": res.n_matches,
              "inliers": res.n_inliers, "condition": res.condition, "method": "pnp" if pnp else method,
              "covariance_kappa": kappa, "covariance_model": covariance if refined else "white",
              **({} if res.field is None else {"covariance_field": res.field}), **align_stats,
              **integ.report(),
              "timings_s": res.timings_s, "tasks": {}}  # no task is offered without a pose
    if len(regions) > 1:
        report["regions"] = {name: {"map_points": len(m), "matches": r.n_matches, "inliers": r.n_inliers,
                                    "solved": i in include,
                                    "message": (f"{r.n_inliers} inliers, fewer than {MIN_INLIERS}: not used; "
                                                if r.success and r.n_inliers < MIN_INLIERS else "") + r.message}
                             for i, (m, r, (name, _)) in enumerate(zip(maps, per, regions, strict=True))}
    if res.success:
        T = res.T_world_base
        std = np.sqrt(np.clip(np.diag(res.covariance), 0.0, None))
        report.update({"T_world_base": T.tolist(), "position_mm": (T[:3, 3] * 1e3).tolist(),
                       "rotation_deg": float(np.rad2deg(rotation_angle(T[:3, :3]))),
                       "position_std_mm": (std[3:] * 1e3).tolist(), "rotation_std_deg": np.rad2deg(std[:3]).tolist(),
                       "covariance": res.covariance.tolist(), "ins_tilt": "absent" if tilt is None else
                       "fused" if fused is not None else "checked"})
        if fused is not None:
            report.update({"T_world_base_vision": T_vision.tolist(),
                           "ins_correction_deg": float(np.rad2deg(np.linalg.norm(fused[:3]))),
                           "ins_correction_mm": float(np.linalg.norm(fused[3:]) * 1e3)})
        # the compensated task is not offered on a refused localisation
        report["tasks"] = ({} if integ.level == "refused" else
                           _retarget_tasks(ds, robot, eps, res.T_world_base, roles["locate"][0].q, res.covariance,
                                           integ.tests))
    if out is not None:
        atomic_write_text(Path(out) / "locate.json", json.dumps(report, indent=2) + "\n")
    if verbose:
        print(f"{ds.name}: {report['map_points']} map points ({kmap.stats}), {res.n_matches} matches, "
              f"{res.n_inliers} inliers")
        for name, r in report.get("regions", {}).items():
            print(f"  region {name}: {r['map_points']} map points, {r['inliers']} inliers"
                  + ("" if r["solved"] else f" - not in the solution: {r['message']}"))
        if res.success:
            p, s = report["position_mm"], report["position_std_mm"]
            print("T_world_base position [mm]: " + ", ".join(f"{v:.2f} ± {e:.2f}" for v, e in zip(p, s, strict=True)))
            print(f"rotation {report['rotation_deg']:.4f} deg (std {np.linalg.norm(report['rotation_std_deg']):.4f})")
            if fused is not None:
                print(f"the vehicle's INS tilt fused: the images' pose moved by {report['ins_correction_deg']:.4f} deg "
                      f"and {report['ins_correction_mm']:.2f} mm (kept as T_world_base_vision)")
            for name, t in report["tasks"].items():
                q = ", ".join(f"{v:.3f}" for v in t["q_command_deg"])
                pr = t["protection_radius_mm"]
                print(f"task {name}: command q = [{q}] deg" + ("" if pr is None else f", tool tip protection radius "
                                                                 f"{pr:.2f} mm")
                      + ("" if t["success"] else f" ({t['message']})"))
        print(res.message)
        pr = report["protection_radius_mm"]
        bound = "" if pr is None else f" (protection radius {pr:.2f} mm, {report['protection_angle_deg']:.3f} deg)"
        print(f"integrity: {integ.level.upper()}{bound}")
        for r in integ.reasons:
            print(f"  - {r}")
    return res, report
