"""The public API of bench.vision (issue 17.5): one match call, one triangulation family, pixels + cameras, and a
SIFT detector that cannot be fed the wrong channel order silently."""

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

import bench.vision as vision
from bench.camera.model import CameraModel, random_camera_model
from bench.geometry.transforms import homogeneous, invert, rot_x, rot_y, rot_z, transform_points
from bench.vision import (
    METHODS,
    MatchResult,
    Triangulation,
    detect_sift,
    match_features,
    match_images,
    triangulate,
    triangulate_linear,
    triangulate_midpoint,
    triangulate_optimal,
    triangulate_pixels,
)
from bench.vision.features import match_descriptors, orientation_filter
from tests.vision.planar_scene import texture

ROOT = Path(__file__).resolve().parents[2]
FUNCTIONS = {"midpoint": triangulate_midpoint, "linear": triangulate_linear, "optimal": triangulate_optimal}


def _scene(rng, cameras, n=80, depth=1.5, n_views=2):
    """Camera poses (V, 4, 4) a few decimetres apart looking along +z, and N points seen inside every image: pixels
    of view 0 drawn inside its image, carried out to random depths, kept if every view sees them."""
    T = [np.eye(4)]
    for _ in range(n_views - 1):
        a = rng.uniform(-0.08, 0.08, 3)
        T.append(homogeneous(rot_x(a[0]) @ rot_y(a[1]) @ rot_z(a[2]), rng.uniform([-0.25, -0.1, -0.05],
                                                                                 [0.25, 0.1, 0.05])))
    T = np.stack(T)
    uv0 = rng.uniform([40, 40], [cameras[0].width - 40, cameras[0].height - 40], (4 * n, 2))
    p = cameras[0].unproject(uv0, normalize=False) * rng.uniform(depth - 0.4, depth + 0.4, (4 * n, 1))
    uv = np.stack([cam.project(transform_points(invert(Tv), p)) for cam, Tv in zip(cameras, T, strict=True)])
    seen = np.all([cam.in_image(u, border=5) for cam, u in zip(cameras, uv, strict=True)], axis=0)
    assert seen.sum() >= n
    return T, p[seen][:n], uv[:, seen][:, :n]


def _normalized(T, p):
    pc = transform_points(invert(T)[:, None], p[None])
    return pc[..., :2] / pc[..., 2:3]


# ------------------------------------------------------------------------------------------------ triangulation


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_exactness_through_pixels_and_cameras(method):
    """Distorted cameras (one per view, and one shared), pixels as the camera chain gives them: every method returns
    the points to 1e-9 m through triangulate_pixels, and the same as on the normalized coordinates."""
    rng = np.random.default_rng(170)
    cams = [random_camera_model(rng, k3=True), random_camera_model(rng)]
    for cameras, views in ((cams, 2), (cams[0], 2), ([cams[0], cams[1], cams[0]], 3)):
        if method == "midpoint" and views != 2:
            continue
        per_view = cameras if isinstance(cameras, list) else [cameras] * views
        T, p, uv = _scene(rng, per_view, n_views=views)
        tri = triangulate_pixels(T, uv, cameras, method)
        assert isinstance(tri, Triangulation) and tri.method == method
        assert tri.valid.all() and np.abs(tri.points - p).max() <= 1e-9
        assert np.abs(tri.depth - _depths(T, p)).max() <= 1e-9 and tri.gap.max() <= 1e-9
        assert tri.rms.max() <= 1e-11  # normalized units
        x = np.stack([c.undistort_pixels(u) for c, u in zip(per_view, uv, strict=True)])
        assert np.array_equal(triangulate(T, x, method).points, tri.points)


def _depths(T, p):
    return transform_points(invert(T)[:, None], p[None])[..., 2]


@pytest.mark.parametrize("method", METHODS)
def test_valid_and_nan_contract(method):
    """Behind a camera, parallel rays, zero baseline: invalid and NaN in every per-point field, for every method;
    the good points in the same batch are untouched."""
    rng = np.random.default_rng(171)
    T = np.stack([np.eye(4), homogeneous(rot_y(0.05), [0.2, 0.0, 0.5])])
    good = np.column_stack([rng.uniform(-0.3, 0.3, (5, 2)), rng.uniform(1.0, 2.0, 5)])
    behind_both = np.array([[0.1, 0.05, -1.5]])  # projects to valid-looking coordinates in both views
    behind_one = np.array([[0.1, 0.0, 0.2]])  # in front of camera 1, behind camera 2 (0.5 m ahead of camera 1)
    p = np.concatenate([good, behind_both, behind_one])
    x = _normalized(T, p)
    assert _depths(T, behind_one)[1, 0] < 0 < _depths(T, behind_one)[0, 0]
    parallel = np.stack([[[0.1, -0.2]], [[0.1, -0.2]]])  # pure translation between two views, same coordinates
    T_par = np.stack([np.eye(4), homogeneous(np.eye(3), [0.1, 0.02, 0.0])])
    tri = FUNCTIONS[method](T, x)
    expected = np.array([True] * 5 + [False, False])
    assert np.array_equal(tri.valid, expected)
    par = FUNCTIONS[method](T_par, parallel)
    zero = FUNCTIONS[method](np.stack([np.eye(4), np.eye(4)]), x[:, :5])  # zero baseline, different pixels
    assert not par.valid.any() and not zero.valid.any()
    for t in (tri, par, zero):
        bad = ~t.valid
        for field in (t.points, t.ray_points):
            assert np.isnan(field[..., bad, :]).all() and np.isfinite(field[..., ~bad, :]).all()
        assert np.isnan(t.depth[:, bad]).all() and (t.depth[:, ~bad] > 0).all()
        assert np.isnan(t.gap[bad]).all() and np.isnan(t.rms[bad]).all()
    assert np.abs(tri.points[:5] - good).max() <= 1e-9


def test_pixel_helper_flags_pixels_the_camera_cannot_undistort():
    """A pixel the camera cannot undistort (NaN from the camera chain's inverse) makes its match invalid, not an
    error; the others are triangulated as without it, and the options (p0) follow the kept matches."""

    class Refusing:  # a camera whose inverse does not converge at one pixel
        def __init__(self, cam, bad):
            self.cam, self.bad = cam, bad

        def undistort_pixels(self, uv):
            x = self.cam.undistort_pixels(uv)
            x[self.bad] = np.nan
            return x

    rng = np.random.default_rng(172)
    cam = random_camera_model(rng)
    T, p, uv = _scene(rng, [cam, cam], n=10)
    for method in METHODS:
        full = triangulate_pixels(T, uv, cam, method)
        part = triangulate_pixels(T, uv, [cam, Refusing(cam, 3)], method)
        assert part.valid.sum() == 9 and not part.valid[3] and np.isnan(part.points[3]).all()
        assert np.isnan(part.depth[:, 3]).all() and np.isnan(part.ray_points[:, 3]).all()
        keep = np.arange(10) != 3
        assert np.allclose(part.points[keep], full.points[keep], rtol=0, atol=1e-12)
    opt = triangulate_pixels(T, uv, [cam, Refusing(cam, 3)], "optimal", p0=p + 0.01)
    assert opt.valid.sum() == 9 and np.abs(opt.points[keep] - p[keep]).max() <= 1e-9


def test_argument_order_is_the_same_for_every_method():
    """(T_ref_cams, x_n), view-major: the same call for every method; lists of per-view arrays equal stacks; swapping
    the views swaps the per-view rows; the thesis-era call (T1, x1, T2, x2) and swapped arguments are refused."""
    rng = np.random.default_rng(173)
    cam = random_camera_model(rng)
    T, p, uv = _scene(rng, [cam, cam], n=30)
    x = np.stack([cam.undistort_pixels(u) for u in uv])
    for method in METHODS:
        a = triangulate(T, x, method)
        b = FUNCTIONS[method]([T[0], T[1]], [x[0], x[1]])
        c = triangulate(T[::-1], x[::-1], method)
        assert np.array_equal(a.points, b.points)
        assert np.abs(c.points - a.points).max() <= 1e-9
        assert np.abs(c.depth[::-1] - a.depth).max() <= 1e-9
        with pytest.raises(ValueError, match="T_ref_cams"):
            FUNCTIONS[method](x, T)  # points first
        with pytest.raises(TypeError):
            FUNCTIONS[method](T[0], x[0], T[1], x[1])  # the old mid-point order
        with pytest.raises(ValueError, match="2 views of points for 3 camera poses"):
            FUNCTIONS[method](np.stack([T[0], T[1], T[1]]), x)
    with pytest.raises(ValueError, match="exactly 2 views"):
        triangulate_midpoint(np.stack([T[0], T[1], T[1]]), np.stack([x[0], x[1], x[1]]))
    K4 = np.stack([np.eye(4), np.eye(4)])
    K4[1, :3, :3] = cam.K  # an intrinsic matrix where a pose belongs
    with pytest.raises(ValueError, match="pose 1 is not a rigid transform"):
        triangulate(K4, x)
    with pytest.raises(ValueError, match="pose 0 is not a rigid transform"):
        triangulate(np.stack([np.diag([1.0, 1.0, -1.0, 1.0]), T[1]]), x)  # a reflection
    with pytest.raises(ValueError, match="method: expected one of"):
        triangulate(T, x, "dlt")
    with pytest.raises(ValueError, match="cameras: 3 camera models for 2 views"):
        triangulate_pixels(T, uv, [cam] * 3)
    with pytest.raises(ValueError, match="cameras: expected a camera model"):
        triangulate_pixels(T, uv, cam.K)
    with pytest.raises(ValueError, match="uv: contains NaN"):
        triangulate_pixels(T, np.where(uv > 300, np.nan, uv), cam)


def test_cross_check_with_opencv_triangulate_points():
    """cv2.triangulatePoints (DLT on pixel projection matrices K [R^T | -R^T t]) against the family, live: noise-free
    all agree to 1e-9 m; with 0.5 px noise the linear method is as accurate as OpenCV's (the two DLTs weight the rows
    differently, so they differ by about the noise's own effect), and the optimal one reprojects no worse than
    OpenCV's point."""
    rng = np.random.default_rng(174)
    pinhole = CameraModel(640, 480, np.array([[700.0, 0.0, 321.0], [0.0, 705.0, 238.0], [0.0, 0.0, 1.0]]))
    T, p, uv = _scene(rng, [pinhole, pinhole], n=60)
    P = [pinhole.K @ invert(Tv)[:3] for Tv in T]

    def opencv(uv_):
        X = cv2.triangulatePoints(P[0], P[1], uv_[0].T.astype(np.float64), uv_[1].T.astype(np.float64))
        return (X[:3] / X[3]).T

    ref = opencv(uv)
    assert np.abs(ref - p).max() <= 1e-9
    for method in METHODS:
        assert np.abs(triangulate_pixels(T, uv, pinhole, method).points - ref).max() <= 1e-9
    noisy = uv + rng.normal(0.0, 0.5, uv.shape)
    ref = opencv(noisy)
    lin = triangulate_pixels(T, noisy, pinhole, "linear")
    err_ours, err_cv = (np.sqrt(np.mean(np.sum((q - p) ** 2, axis=1))) for q in (lin.points, ref))
    assert 0.8 < err_ours / err_cv < 1.25
    opt = triangulate_pixels(T, noisy, pinhole, "optimal")
    x = np.stack([pinhole.undistort_pixels(u) for u in noisy])
    ref_rms = np.sqrt(np.mean(np.sum((x - _normalized(T, ref)) ** 2, axis=-1), axis=0))
    assert np.all(opt.rms <= ref_rms + 1e-15)
    # distorted camera: OpenCV's own undistortion (iterated to convergence; it has no skew) then normalized
    # projection matrices
    cam = random_camera_model(rng, k3=True, skew=False)
    T, p, uv = _scene(rng, [cam, cam], n=60)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xn = [cv2.undistortPoints(u.reshape(-1, 1, 2), cam.K, cam.dist, R=np.eye(3), P=np.eye(3), criteria=crit)
          .reshape(-1, 2) for u in uv]
    X = cv2.triangulatePoints(invert(T[0])[:3], invert(T[1])[:3], xn[0].T, xn[1].T)
    assert np.abs((X[:3] / X[3]).T - triangulate_pixels(T, uv, cam, "linear").points).max() <= 1e-9


# ------------------------------------------------------------------------------------------------ matching


def _texture(rng, h=360, w=480):
    """A grey texture rich in SIFT keypoints (tests.vision.planar_scene's), cropped to h x w."""
    return np.ascontiguousarray(texture(rng)[:h, :w])


def test_match_images_agrees_with_the_homography():
    """An image and its warp by a known homography (25 deg rotation, scale, perspective): the matches map onto each
    other through the homography, the orientation filter is centred on the rotation, and the counts shrink stage by
    stage."""
    rng = np.random.default_rng(175)
    img1 = _texture(rng)
    h, w = img1.shape
    c, s = np.cos(np.deg2rad(25.0)), np.sin(np.deg2rad(25.0))
    # image rotated 25 deg counter-clockwise on screen (y down), about the centre, scaled by 0.9, slight perspective
    A = np.array([[0.9 * c, 0.9 * s, 0.0], [-0.9 * s, 0.9 * c, 0.0], [1e-4, -5e-5, 1.0]])
    C = np.array([[1.0, 0.0, w / 2], [0.0, 1.0, h / 2], [0.0, 0.0, 1.0]])
    H = C @ A @ np.linalg.inv(C)
    img2 = cv2.warpPerspective(img1, H, (w, h), flags=cv2.INTER_LINEAR, borderValue=128)
    res = match_images(img1, img2)
    assert isinstance(res, MatchResult) and len(res) > 80
    pred = cv2.perspectiveTransform(res.uv1.reshape(-1, 1, 2), H).reshape(-1, 2)
    err = np.linalg.norm(pred - res.uv2, axis=1)
    assert np.mean(err < 1.5) > 0.95 and np.median(err) < 0.5
    assert abs(res.orientation_centre_deg + 25.0) < 2.0  # keypoint angles counter-clockwise: image 2 turned by +25
    assert np.all(np.abs(res.orientation_change_deg - res.orientation_centre_deg) <= 20.0)
    n = res.counts
    assert list(n) == ["keypoints1", "keypoints2", "ratio_test", "orientation_filter"]
    assert n["keypoints1"] >= n["ratio_test"] >= n["orientation_filter"] == len(res)
    assert np.all(res.ratio <= 0.8) and res.distance.shape == res.i1.shape == res.uv2[:, 0].shape
    # the same as the two stages called by hand (what bench.vision.insitu did before)
    m, _ = orientation_filter(res.features1, res.features2, match_descriptors(res.features1, res.features2))
    assert np.array_equal(m.i1, res.i1) and np.array_equal(m.i2, res.i2)
    mutual = match_features(res.features1, res.features2, mutual=True)
    assert list(mutual.counts) == ["keypoints1", "keypoints2", "ratio_test", "mutual", "orientation_filter"]
    assert mutual.counts["mutual"] <= n["ratio_test"] and len(mutual) <= len(res)
    with pytest.raises(ValueError, match="orientation_tol_deg"):
        match_features(res.features1, res.features2, orientation_tol_deg=0.0)


def test_match_images_from_files_equals_arrays(tmp_path):
    rng = np.random.default_rng(176)
    img1 = _texture(rng)
    img2 = np.ascontiguousarray(np.roll(img1, (7, -11), axis=(0, 1)))
    colour2 = cv2.cvtColor(img2, cv2.COLOR_GRAY2BGR)
    cv2.imwrite(str(tmp_path / "a.png"), img1)
    cv2.imwrite(str(tmp_path / "b.png"), colour2)
    a = match_images(img1, img2)
    b = match_images(tmp_path / "a.png", str(tmp_path / "b.png"))
    c = match_images(tmp_path / "a.png", colour2, channel_order="bgr")  # a file and an array together
    for r in (b, c):
        assert np.array_equal(a.uv1, r.uv1) and np.array_equal(a.uv2, r.uv2) and r.counts == a.counts
    assert np.abs(np.median(a.uv1 - a.uv2, axis=0) - [11, -7]).max() < 0.05


# ------------------------------------------------------------------------------------------------ channel order


def test_detect_sift_refuses_a_colour_array_without_its_channel_order(tmp_path):
    rng = np.random.default_rng(177)
    grey = _texture(rng)
    rgb = np.dstack([grey, grey, _texture(rng)])  # a blue channel unlike the others: the weights matter
    bgr = np.ascontiguousarray(rgb[..., ::-1])
    cv2.imwrite(str(tmp_path / "c.png"), bgr)  # imwrite takes BGR: the file holds the RGB image
    from_file = cv2.imread(str(tmp_path / "c.png"))  # ... and imread gives BGR back
    for img in (rgb, bgr, from_file, np.dstack([rgb, np.full(grey.shape, 255, np.uint8)])):
        with pytest.raises(ValueError, match=r"channel_order='rgb' or 'bgr'.*cv2\.imread gives 'bgr'"):
            detect_sift(img)
        with pytest.raises(ValueError, match="channel_order='rgb' or 'bgr'"):
            match_images(img, grey)
    f_rgb = detect_sift(rgb, channel_order="rgb")
    f_bgr = detect_sift(bgr, channel_order="bgr")
    f_file = detect_sift(tmp_path / "c.png")
    assert len(f_rgb) > 50 and np.array_equal(f_rgb.uv, f_bgr.uv) and np.array_equal(f_rgb.uv, f_file.uv)
    assert np.array_equal(f_rgb.descriptors, f_bgr.descriptors)
    wrong = detect_sift(rgb, channel_order="bgr")  # what the silent default used to do to a cv2.imread image
    assert not np.array_equal(wrong.uv, f_rgb.uv)
    assert np.array_equal(detect_sift(grey, channel_order="rgb").uv, detect_sift(grey).uv)  # ignored for grey
    assert np.array_equal(detect_sift(grey[..., None]).uv, detect_sift(grey).uv)
    with pytest.raises(ValueError, match="channel_order: expected one of"):
        detect_sift(rgb, channel_order="RGB ")
    with pytest.raises(ValueError, match="channel_order: not used for an image file"):
        detect_sift(tmp_path / "c.png", channel_order="bgr")
    with pytest.raises(ValueError, match="uint8"):
        detect_sift(rgb.astype(np.float32), channel_order="rgb")
    from bench.errors import ConfigError

    with pytest.raises(ConfigError, match="a folder, not an image file"):
        detect_sift(tmp_path)
    with pytest.raises(ConfigError, match="missing.png: <file>: image not found"):
        detect_sift(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"not an image at all")
    with pytest.raises(ConfigError, match="junk.png"):
        detect_sift(tmp_path / "junk.png")


# ------------------------------------------------------------------------------------------------ the docs


def test_docs_example_runs():
    """docs/vision.md's public-API example runs as written."""
    text = (ROOT / "docs" / "vision.md").read_text()
    section = text[text.index("## Public API"):]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, "docs/vision.md: no python example in the Public API section"
    namespace: dict = {}
    exec(compile(blocks[0], "docs/vision.md", "exec"), namespace)  # noqa: S102 - our own documentation
    tri = namespace["tri"]
    assert tri.valid.sum() > 500 and abs(np.median(tri.points[tri.valid, 2]) - 1.2) < 1e-3


def test_public_names():
    assert set(vision.__all__) <= set(dir(vision))
    for name in ("match_images", "match_features", "detect_sift", "triangulate", "triangulate_pixels",
                 "triangulate_midpoint", "triangulate_linear", "triangulate_optimal", "Triangulation", "MatchResult"):
        assert name in vision.__all__
