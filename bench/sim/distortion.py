"""The simulator's lens/housing distortion stage: a supersampled pinhole render -> the target camera's image.

Contract with the renderer (``bench/sim/render.py``): it renders a pinhole image (RGB, and optionally depth in m) with
a known intrinsic matrix ``K_render`` (no distortion) at a supersampled resolution; :func:`render_K` tells it which
``K_render`` and size cover the target camera's distorted field of view. This stage maps that render to the target
camera (``K`` with skew, distortion of Eq. 75-76, resolution) by an exact inverse warp:

* every output pixel ``(u, v)`` covers the footprint ``[u - 1/2, u + 1/2] x [v - 1/2, v + 1/2]`` (OpenCV's pixel
  convention, ``(0, 0)`` the centre of the top-left pixel); it is integrated by ``s x s`` sub-samples at
  ``u - 1/2 + (i + 1/2) / s`` (a box filter over the footprint, the anti-aliasing);
* each sub-sample goes back through the target camera - ``K^-1`` (Eq. 51), the inverse distortion by Newton
  iteration to 1e-12 (:func:`bench.camera.model.undistort`) - to its ideal normalised coordinate, then through
  ``K_render`` into the render's pixel grid;
* the render is sampled there bilinearly (``cv2.remap``; OpenCV quantises the bilinear weights to 1/32 of a render
  pixel, i.e. ``1/(32 s)`` of an output pixel) and the ``s x s`` samples are averaged.

The maps are built once per (camera, supersampling, ``K_render``, render size) and cached. Depth is never averaged
across edges (a mean of a foreground and a background depth is a surface that does not exist): ``"center"`` takes
the render pixel nearest to the ideal position of the output pixel's centre, ``"min"`` the nearest surface among the
``s x s`` sub-samples (nearest-neighbour each). A depth value belongs to a 3D point (z-depth or range alike), so it
is carried unchanged.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from bench.camera.model import CameraModel, check_K, from_pixels, to_pixels, undistort

#: how many map sets (each ~6 bytes per sub-sample) the module keeps
_CACHE_SIZE = 4
_MAP_CACHE: OrderedDict = OrderedDict()


@dataclass(frozen=True)
class RenderSpec:
    """What the pinhole renderer must produce for a :class:`DistortionStage`.

    Attributes
    ----------
    K : ndarray (3, 3)
        Pinhole intrinsics of the render (px of the render), no skew: ``fx_r = s fx``, ``fy_r = s fy``.
    width, height : int
        Render size (px).
    supersample : int
    """

    K: np.ndarray
    width: int
    height: int
    supersample: int


def check_supersample(supersample) -> int:
    """Validate the supersampling factor: an integer in 1..16."""
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or not 1 <= supersample <= 16:
        raise ValueError(f"supersample: expected an integer in 1..16, got {supersample!r}")
    return int(supersample)


def subsample_coordinates(n: int, supersample: int) -> np.ndarray:
    """Positions (px) of the ``n * s`` sub-samples along one image axis: ``k // s - 1/2 + (k % s + 1/2) / s``."""
    return (np.arange(n * supersample) + 0.5) / supersample - 0.5


def _undistort_checked(camera: CameraModel, uv, x0=None, what="image"):
    res = undistort(from_pixels(uv, camera.K), camera.dist, full_output=True, x0=x0)
    if not res.success:
        raise ValueError(f"camera {camera.name!r}: dist: the distortion cannot be inverted over the {what} "
                         f"({res.message})")
    return res.x_n


def render_K(camera: CameraModel, supersample: int, margin: int = 2) -> RenderSpec:
    """The pinhole render (intrinsics and size) that covers ``camera``'s distorted field of view.

    The ideal directions of the outermost sub-samples of the image (its border; a one-to-one distortion attains
    the extremes of the ideal coordinates there) give the bounding box in normalised coordinates; the render has
    ``s`` times the target's focal lengths and reaches ``margin`` render pixels beyond the box on every side
    (bilinear sampling needs one).

    Parameters
    ----------
    camera : CameraModel
    supersample : int
        Sub-samples per output pixel along each axis (1..16).
    margin : int
        Extra render pixels on every side (>= 1).

    Returns
    -------
    RenderSpec
    """
    s = check_supersample(supersample)
    if isinstance(margin, bool) or not isinstance(margin, (int, np.integer)) or margin < 1:
        raise ValueError(f"margin: expected an integer >= 1 (render px), got {margin!r}")
    us, vs = subsample_coordinates(camera.width, s), subsample_coordinates(camera.height, s)
    border = np.concatenate([np.stack([us, np.full_like(us, vs[0])], -1), np.stack([us, np.full_like(us, vs[-1])], -1),
                             np.stack([np.full_like(vs, us[0]), vs], -1), np.stack([np.full_like(vs, us[-1]), vs], -1)])
    x_n = _undistort_checked(camera, border, what="image border")
    lo, hi = x_n.min(axis=0), x_n.max(axis=0)
    f_r = np.array([s * camera.fx, s * camera.fy])
    size = np.ceil((hi - lo) * f_r).astype(int) + 1 + 2 * margin
    c_r = margin - f_r * lo
    K = np.array([[f_r[0], 0.0, c_r[0]], [0.0, f_r[1], c_r[1]], [0.0, 0.0, 1.0]])
    return RenderSpec(K, int(size[0]), int(size[1]), s)


def ideal_subsample_grid(camera: CameraModel, supersample: int) -> np.ndarray:
    """Ideal normalised coordinates ``(H s, W s, 2)`` of all sub-samples of the image (exact, Newton to 1e-12).

    The output pixel centres are undistorted first; their correction ``x_n - x_d``, a smooth field, is resized
    linearly to the sub-sample grid (``cv2.resize`` uses the same half-pixel convention) as the starting point of
    the Newton iteration, which then needs one or two steps per sub-sample.
    """
    s = check_supersample(supersample)
    W, H = camera.width, camera.height
    uu, vv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    uv_c = np.stack([uu, vv], axis=-1)
    xd_c = from_pixels(uv_c, camera.K)
    x_c = _undistort_checked(camera, uv_c, what="pixel centres")
    if s == 1:
        return x_c
    corr = cv2.resize((x_c - xd_c).astype(np.float64), (W * s, H * s), interpolation=cv2.INTER_LINEAR)
    uu, vv = np.meshgrid(subsample_coordinates(W, s), subsample_coordinates(H, s))
    uv = np.stack([uu, vv], axis=-1)
    xd = from_pixels(uv, camera.K)
    return _undistort_checked(camera, uv, x0=xd + corr, what="sub-samples")


@dataclass(frozen=True)
class _Maps:
    sub1: np.ndarray  # fixed-point maps of the sub-samples (cv2.convertMaps, CV_16SC2 + CV_16UC1)
    sub2: np.ndarray
    sub_x: np.ndarray  # float32 maps of the sub-samples (for nearest-neighbour depth)
    sub_y: np.ndarray
    ctr_x: np.ndarray  # float32 maps of the output pixel centres
    ctr_y: np.ndarray


class DistortionStage:
    """Warp supersampled pinhole renders to ``camera``'s distorted image (see the module docstring).

    Parameters
    ----------
    camera : CameraModel
        The target camera (resolution, ``K`` with skew, distortion).
    supersample : int
        Sub-samples per output pixel along each axis (1..16); the render should have ``s`` times the focal length.
    """

    def __init__(self, camera: CameraModel, supersample: int):
        if not isinstance(camera, CameraModel):
            raise ValueError(f"camera: expected a CameraModel, got {type(camera).__name__}")
        self.camera = camera
        self.supersample = check_supersample(supersample)

    def render_spec(self, margin: int = 2) -> RenderSpec:
        """:func:`render_K` for this stage."""
        return render_K(self.camera, self.supersample, margin)

    def maps(self, K_render, render_size) -> _Maps:
        """The (cached) remap tables for a render with intrinsics ``K_render`` and size ``(width, height)``."""
        K_r = check_K(K_render, "K_render")
        Wr, Hr = (int(v) for v in render_size)
        cam = self.camera
        key = ((cam.width, cam.height, cam.K.tobytes(), cam.dist.tobytes(), self.supersample), K_r.tobytes(), Wr, Hr)
        if key in _MAP_CACHE:
            _MAP_CACHE.move_to_end(key)
            return _MAP_CACHE[key]
        s, cam = self.supersample, self.camera
        uv_r = to_pixels(ideal_subsample_grid(cam, s), K_r)
        lo, hi = uv_r.reshape(-1, 2).min(axis=0), uv_r.reshape(-1, 2).max(axis=0)
        if lo[0] < 0 or lo[1] < 0 or hi[0] > Wr - 1 or hi[1] > Hr - 1:
            spec = render_K(cam, s)
            raise ValueError(f"K_render: a {Wr}x{Hr} render does not cover the distorted field of view (needs u in "
                             f"[{lo[0]:.1f}, {hi[0]:.1f}], v in [{lo[1]:.1f}, {hi[1]:.1f}]); render_K() suggests "
                             f"{spec.width}x{spec.height}, K {np.round(spec.K, 3).tolist()}")
        sub_x, sub_y = uv_r[..., 0].astype(np.float32), uv_r[..., 1].astype(np.float32)
        sub1, sub2 = cv2.convertMaps(sub_x, sub_y, cv2.CV_16SC2)
        uu, vv = np.meshgrid(np.arange(cam.width, dtype=float), np.arange(cam.height, dtype=float))
        ctr = to_pixels(_undistort_checked(cam, np.stack([uu, vv], -1), what="pixel centres"), K_r)
        maps = _Maps(sub1, sub2, sub_x, sub_y, ctr[..., 0].astype(np.float32), ctr[..., 1].astype(np.float32))
        _MAP_CACHE[key] = maps
        while len(_MAP_CACHE) > _CACHE_SIZE:
            _MAP_CACHE.popitem(last=False)
        return maps

    def warp_image(self, image, K_render) -> np.ndarray:
        """The distorted image ``(H, W[, C])`` of a pinhole render ``image (H_r, W_r[, C])`` with ``K_render``.

        Integer images are computed in float32 and rounded back to their dtype; float images stay float32.
        """
        img = np.asarray(image)
        if img.ndim not in (2, 3) or img.shape[0] < 2 or img.shape[1] < 2:
            raise ValueError(f"image: expected (H, W) or (H, W, C), got shape {img.shape}")
        if img.dtype.kind == "f" and not np.all(np.isfinite(img)):
            raise ValueError("image: contains NaN or inf")
        maps = self.maps(K_render, (img.shape[1], img.shape[0]))
        src = img.astype(np.float32)
        chans = [src] if src.ndim == 2 or src.shape[2] <= 4 else [src[..., i] for i in range(src.shape[2])]
        parts = [cv2.remap(c, maps.sub1, maps.sub2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                 for c in chans]
        sub = parts[0] if len(parts) == 1 else np.stack(parts, axis=-1)
        s, W, H = self.supersample, self.camera.width, self.camera.height
        if s == 1:
            out = sub
        elif sub.ndim == 2 or sub.shape[2] <= 4:  # INTER_AREA at an integer factor is the exact block mean
            out = cv2.resize(sub, (W, H), interpolation=cv2.INTER_AREA)
        else:
            out = sub.reshape(H, s, W, s, sub.shape[2]).mean(axis=(1, 3), dtype=np.float32)
        if img.dtype.kind in "ui":
            info = np.iinfo(img.dtype)
            return np.clip(np.rint(out), info.min, info.max).astype(img.dtype)
        return out

    def warp_depth(self, depth, K_render, mode: str = "center") -> np.ndarray:
        """The depth ``(H, W)`` (m) seen by the distorted camera, never averaged (see the module docstring).

        Parameters
        ----------
        depth : array_like (H_r, W_r)
            Render depth (m); background as a large value or inf (``"min"`` picks the nearest surface).
        K_render : array_like (3, 3)
        mode : {"center", "min"}
        """
        d = np.asarray(depth, dtype=np.float32)
        if d.ndim != 2:
            raise ValueError(f"depth: expected (H, W), got shape {d.shape}")
        if np.any(np.isnan(d)):
            raise ValueError("depth: contains NaN")
        maps = self.maps(K_render, (d.shape[1], d.shape[0]))
        if mode == "center":
            return cv2.remap(d, maps.ctr_x, maps.ctr_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        if mode == "min":
            sub = cv2.remap(d, maps.sub_x, maps.sub_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
            s, W, H = self.supersample, self.camera.width, self.camera.height
            return sub.reshape(H, s, W, s).min(axis=(1, 3))
        raise ValueError(f"mode: expected 'center' or 'min', got {mode!r}")

    def apply(self, image, K_render, depth=None, depth_mode: str = "center"):
        """Warp a render: returns ``(image, depth)`` (depth ``None`` when not given)."""
        out = self.warp_image(image, K_render)
        return out, (None if depth is None else self.warp_depth(depth, K_render, depth_mode))
