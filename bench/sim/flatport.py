"""Physically based flat-port refraction in the renderer: the image of a pinhole render through a plane glass port.

The port's geometry and optics - :class:`~bench.camera.flatport.FlatPort`, Snell's law, ray tracing and the forward
projection - live in :mod:`bench.camera.flatport`, shared with the pipeline's refractive camera; this module adds

* :class:`FlatPortStage` - the image of a pinhole render (RGB + z-depth from the same camera centre) through the
  port, by per-pixel ray tracing (see the class docstring).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from bench.camera.flatport import FlatPort, check_port, trace_rays
from bench.camera.model import CameraModel, check_K, from_pixels, unproject_pinhole
from bench.sim.distortion import RenderSpec, check_supersample, subsample_coordinates
from bench.sim.parallel import band_edges, map_bands

# ----------------------------------------------------------------------------------------------------------------------
# the image stage
# ----------------------------------------------------------------------------------------------------------------------
_CACHE_SIZE = 4
_TRACE_CACHE: OrderedDict = OrderedDict()


@dataclass(frozen=True)
class FlatPortImage:
    """Output of :meth:`FlatPortStage.apply`.

    Attributes
    ----------
    image : ndarray (H, W[, C])
        The image through the port (dtype of the render).
    depth : ndarray (H, W) float
        z (m, camera frame) of the point seen by each pixel centre's ray; inf where it sees the background.
    water_path : ndarray (H, W) float
        Path length (m) in water of each pixel centre's ray, from the outer glass surface to the point; inf for the
        background (the water path the medium stage needs).
    converged_fraction : float
        Fraction of the finite-depth sub-samples whose depth iteration converged.
    unresolved : ndarray (H, W) int
        Sub-samples per pixel that did not converge (occlusion boundaries) and took the background.
    """

    image: np.ndarray
    depth: np.ndarray
    water_path: np.ndarray
    converged_fraction: float
    unresolved: np.ndarray


class FlatPortStage:
    """The image of a pinhole render seen through a flat port (per-pixel ray tracing).

    For every output pixel ``s x s`` sub-rays (same sub-sample positions and box filter as
    :class:`bench.sim.distortion.DistortionStage`) leave the camera centre in air - through ``K_out^-1`` (Eq. 51), or
    through ``lens.unproject`` when a lens :class:`CameraModel` (the housing's inner camera with its distortion,
    Eq. 75-76) is given - and are traced through both glass surfaces into water (:func:`trace_rays`, cached). The
    point a water ray ``o + lambda w`` hits is found with the depth buffer of the pinhole render, rendered from the
    same camera centre: starting from the render depth in the ray's far direction ``w``, the fixed-point iteration
    ``lambda <- (z_r(K_render pi(o + lambda w)) - o_z) / w_z`` makes the point's z equal to the render depth where
    the point projects. It contracts fast because the origins ``o`` are a few cm off the centre (the parallax per
    metre of ``lambda`` is small); it stops at ``|d lambda| <= tol_rel lambda`` or, for the sub-rays that only
    sample the colour, when the sample point moves by less than ``tol_px`` render px (0.001 px by default, 30 times
    below the 1/32 px resolution of ``cv2.remap``'s weights). The RGB is then sampled bilinearly
    at the converged render pixel and the ``s x s`` samples are averaged.

    Residual approximations (documented, measured in the tests): the depth buffer is interpolated bilinearly in z
    (exact for fronto-parallel planes, second order for slanted ones), sampled by ``cv2.remap`` (bilinear weights
    quantised to 1/32 render px); a surface hidden from the pinhole centre but visible from the shifted origin ``o``
    (dis-occlusion, a few render px wide at depth edges) cannot be seen in a single-centre render: such rays converge
    onto the occluder or oscillate. Sub-rays that do not converge take ``background`` (default: the render sampled in
    the ray's direction at infinity); rays whose render depth is infinite see the background at infinity, which is
    exact (no parallax at infinity). The test with a near half-plane (0.4 m) in front of a wall (1.0 m), edge 6 cm
    off the axis, ``f = 160`` px: the stage differs from an exact ray trace only in a 1-2 px band next to the edge
    (predicted analytically as the wall points the shifted rays see but the centre does not) and by <= 0.3 DN
    elsewhere.

    Parameters
    ----------
    K_out : array_like (3, 3)
        Intrinsics of the output image (px); ignored in favour of ``lens.K`` when ``lens`` is given (must match).
    size_out : (int, int)
        ``(width, height)`` of the output (px).
    port : FlatPort
    supersample : int
        Sub-rays per output pixel along each axis (1..16).
    lens : CameraModel, optional
        The inner camera (lens distortion applied in ray space, before the port).
    background : sequence of float, optional
        Colour of non-converged sub-rays; ``None`` samples the render at the ray's direction at infinity.
    """

    def __init__(self, K_out, size_out, port: FlatPort, supersample: int, lens: CameraModel | None = None,
                 background=None):
        self.port = check_port(port)
        self.supersample = check_supersample(supersample)
        K = check_K(K_out, "K_out")
        try:
            W, H = (int(v) for v in size_out)
        except (TypeError, ValueError):
            raise ValueError(f"size_out: expected (width, height), got {size_out!r}") from None
        if W < 1 or H < 1:
            raise ValueError(f"size_out: expected positive (width, height), got {size_out!r}")
        if lens is not None:
            if not isinstance(lens, CameraModel):
                raise ValueError(f"lens: expected a CameraModel, got {type(lens).__name__}")
            if lens.size != (W, H) or not np.allclose(lens.K, K):
                raise ValueError(f"lens: its K and size {lens.size} must equal K_out and size_out {(W, H)}")
        self.K_out, self.width, self.height, self.lens = K, W, H, lens
        self.background = None if background is None else np.asarray(background, dtype=np.float32).ravel()

    # --- rays ---------------------------------------------------------------------------------------------------------
    def _key(self, which):
        lens = None if self.lens is None else (self.lens.K.tobytes(), self.lens.dist.tobytes())
        p = self.port
        return (which, self.K_out.tobytes(), self.width, self.height, self.supersample, lens,
                (p.d0, p.t, p.n_air, p.n_glass, p.n_water, p.tilt.tobytes(), p.decentre.tobytes()))

    def rays(self, which: str = "sub"):
        """Cached ``(origin, direction, ok)`` in water for the sub-samples (``"sub"``, ``(H s, W s)``) or the pixel
        centres (``"centre"``, ``(H, W)``)."""
        key = self._key(which)
        if key in _TRACE_CACHE:
            _TRACE_CACHE.move_to_end(key)
            return _TRACE_CACHE[key]
        s = self.supersample if which == "sub" else 1
        uu, vv = np.meshgrid(subsample_coordinates(self.width, s), subsample_coordinates(self.height, s))
        uv = np.stack([uu, vv], -1)
        dirs = self.lens.unproject(uv) if self.lens is not None else unproject_pinhole(from_pixels(uv, self.K_out))
        o, w, ok = trace_rays(dirs, self.port)
        if not np.all(ok):
            raise ValueError(f"port: {np.count_nonzero(~ok)} ray(s) of the image are totally reflected or miss the "
                             "port (tilt too large for the field of view)")
        _TRACE_CACHE[key] = (o, w, ok)
        while len(_TRACE_CACHE) > _CACHE_SIZE:
            _TRACE_CACHE.popitem(last=False)
        return o, w, ok

    def render_spec(self, z_min: float, margin: int = 2) -> RenderSpec:
        """A pinhole render (intrinsics, size) that covers every point the output sees at depths ``z >= z_min`` (m).

        Points on a water ray at ``z >= z_min`` project between the ray's point at ``z_min`` and its direction at
        infinity; the render's focal lengths are ``s n_water / n_air`` times the output's (the port magnifies).
        """
        if not np.isfinite(z_min) or z_min <= self.port.h + self.port.t:
            raise ValueError(f"z_min: must exceed the outer glass surface ({self.port.h + self.port.t} m), got "
                             f"{z_min}")
        o, w, _ = self.rays("sub")
        border = np.concatenate([o[0], o[-1], o[:, 0], o[:, -1]]), np.concatenate([w[0], w[-1], w[:, 0], w[:, -1]])
        ob, wb = border
        lam = (z_min - ob[:, 2]) / wb[:, 2]
        pts = ob + lam[:, None] * wb
        x_n = np.concatenate([pts[:, :2] / pts[:, 2:], wb[:, :2] / wb[:, 2:]])
        lo, hi = x_n.min(axis=0), x_n.max(axis=0)
        mag = self.supersample * self.port.n_water / self.port.n_air
        f_r = mag * np.array([self.K_out[0, 0], self.K_out[1, 1]])
        size = np.ceil((hi - lo) * f_r).astype(int) + 1 + 2 * margin
        c_r = margin - f_r * lo
        K = np.array([[f_r[0], 0.0, c_r[0]], [0.0, f_r[1], c_r[1]], [0.0, 0.0, 1.0]])
        return RenderSpec(K, int(size[0]), int(size[1]), self.supersample)

    # --- the depth iteration ------------------------------------------------------------------------------------------
    def projection(self, which: str, K_render) -> _RayProjection:
        """Cached :class:`_RayProjection` of the ``which`` rays (see :meth:`rays`) into a render with ``K_render``."""
        K_r = check_K(K_render, "K_render")
        key = self._key(which) + (K_r.tobytes(),)
        if key in _PROJ_CACHE:
            _PROJ_CACHE.move_to_end(key)
            return _PROJ_CACHE[key]
        o, w, _ = self.rays(which)
        proj = _RayProjection.build(o, w, K_r)
        _PROJ_CACHE[key] = proj
        while len(_PROJ_CACHE) > _CACHE_SIZE:
            _PROJ_CACHE.popitem(last=False)
        return proj

    @staticmethod
    def _solve(o, w, depth32, K_r, max_iterations, tol_rel):
        """Fixed point of the ray parameter for arrays ``o, w (..., 3)``: returns ``(lam, uv, status)`` (flat).

        status: 0 converged on a finite surface, 1 background (infinite depth), 2 not converged.
        """
        proj = _RayProjection.build(np.asarray(o, float).reshape(1, -1, 3), np.asarray(w, float).reshape(1, -1, 3),
                                    check_K(K_r, "K_render"))
        lam, u, v, status = _depth_fixed_point(proj, np.asarray(depth32, np.float32), max_iterations, tol_rel)
        return lam.ravel(), np.stack([u.ravel(), v.ravel()], -1).astype(float), status.ravel()

    def apply(self, image, depth, K_render, *, max_iterations: int = 12, tol_rel: float = 1e-6,
              tol_px: float = 1e-3) -> FlatPortImage:
        """The image through the port of a pinhole render ``image (H_r, W_r[, C])`` with z-depth ``depth (H_r, W_r)``
        (m, inf = background) and intrinsics ``K_render`` (no skew).

        The output's row bands are traced in parallel threads (:mod:`bench.sim.parallel`; every ray is independent,
        so the result does not depend on the split). Raises a one-line ``ValueError`` when a converged hit point lies
        outside the render (see :meth:`render_spec`).
        """
        img = np.asarray(image)
        if img.ndim not in (2, 3) or img.shape[0] < 2 or img.shape[1] < 2:
            raise ValueError(f"image: expected (H, W) or (H, W, C), got shape {img.shape}")
        if img.dtype.kind == "f" and not np.all(np.isfinite(img)):
            raise ValueError("image: contains NaN or inf")
        d = np.asarray(depth)
        if d.shape != img.shape[:2]:
            raise ValueError(f"depth: expected shape {img.shape[:2]} (the image's), got {d.shape}")
        if d.dtype.kind not in "fiu" or np.isnan(d).any() or (d <= 0).any():
            raise ValueError("depth: must be > 0 (m) or inf, no NaN")
        K_r = check_K(K_render, "K_render")
        if K_r[0, 1] != 0:
            raise ValueError("K_render: the render must have no skew")
        Hr, Wr = d.shape
        d32 = np.ascontiguousarray(d, dtype=np.float32)
        s, W, H = self.supersample, self.width, self.height
        if self.background is not None and img.ndim == 3 and self.background.size not in (1, img.shape[2]):
            raise ValueError(f"background: expected 1 or {img.shape[2]} values, got {self.background.size}")
        src = img.astype(np.float32)
        chans = [src] if src.ndim == 2 or src.shape[2] <= 4 else [src[..., i] for i in range(src.shape[2])]
        p_sub, p_ctr = self.projection("sub", K_r), self.projection("centre", K_r)

        def band(r0, r1):
            """Output rows r0..r1: the box-filtered colour, the centre rays' (lam, z) and the sub-ray status."""
            ps = p_sub.rows(r0 * s, r1 * s)
            _, u, v, status = _depth_fixed_point(ps, d32, max_iterations, tol_rel, tol_px)
            hit = status == 0
            if hit.any():
                # the whole band's maps inside the render imply the hits are; otherwise check the hits alone
                if u.min() < -0.5 or v.min() < -0.5 or u.max() > Wr - 0.5 or v.max() > Hr - 0.5:
                    u_hit, v_hit = u[hit], v[hit]
                    if u_hit.min() < -0.5 or v_hit.min() < -0.5 or u_hit.max() > Wr - 0.5 or v_hit.max() > Hr - 0.5:
                        raise ValueError(f"K_render: a {Wr}x{Hr} render does not cover the points the port image "
                                         "sees; use FlatPortStage.render_spec(z_min)")
            m1, m2 = cv2.convertMaps(u, v, cv2.CV_16SC2)
            parts = [cv2.remap(c, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) for c in chans]
            sub = parts[0] if len(parts) == 1 else np.stack(parts, axis=-1)
            unresolved = status == 2
            if self.background is not None and unresolved.any():
                bg = self.background if sub.ndim == 3 else self.background[:1]
                sub[unresolved] = bg if sub.ndim == 3 else bg[0]
            if s == 1:
                out = sub
            elif sub.ndim == 2 or sub.shape[2] <= 4:  # INTER_AREA at an integer factor: the exact block mean
                out = cv2.resize(sub, (W, r1 - r0), interpolation=cv2.INTER_AREA)
            else:
                out = sub.reshape(r1 - r0, s, W, s, sub.shape[2]).mean(axis=(1, 3), dtype=np.float32)
            pc = p_ctr.rows(r0, r1)
            lam_c, _, _, st_c = _depth_fixed_point(pc, d32, max_iterations, tol_rel)
            lam_c = np.where(st_c == 0, lam_c, np.inf)
            z_c = np.where(np.isfinite(lam_c), pc.o_z + np.where(np.isfinite(lam_c), lam_c, 0) * pc.w_z, np.inf)
            unres = unresolved.reshape(r1 - r0, s, W, s).sum(axis=(1, 3)).astype(np.int32)
            return out, lam_c, z_c, unres, int(np.count_nonzero(hit)), int(np.count_nonzero(status != 1))

        res = map_bands(band, band_edges(H))
        out = np.concatenate([r[0] for r in res]) if len(res) > 1 else res[0][0]
        if img.dtype.kind in "ui":
            info = np.iinfo(img.dtype)
            out = np.clip(np.rint(out), info.min, info.max).astype(img.dtype)
        lam_c, z_c, unres = (np.concatenate([r[k] for r in res]) for k in (1, 2, 3))
        frac = float(sum(r[4] for r in res) / max(1, sum(r[5] for r in res)))
        return FlatPortImage(out, z_c, lam_c, frac, unres)


# ----------------------------------------------------------------------------------------------------------------------
# the depth fixed point, vectorised
# ----------------------------------------------------------------------------------------------------------------------
_PROJ_CACHE: OrderedDict = OrderedDict()
#: the fixed point runs over the whole ray grid while more than this fraction of rays is active, then on the
#: compacted active rays only (gathering costs more than sampling a few converged rays again)
_DENSE_FRACTION = 0.2


@dataclass(frozen=True)
class _RayProjection:
    """Where the points of a grid of water rays ``o + lambda w`` project in a pinhole render ``K_r`` (no skew).

    With ``z`` the point's z-coordinate (camera frame), ``lambda = (z - o_z) / w_z`` and the point's normalised image
    coordinate is ``x = w_x / w_z + (o_x - o_z w_x / w_z) / z`` (exact), so its render pixel is

        ``u(z) = u_inf + a_u / z``,  ``v(z) = v_inf + a_v / z``,

    ``(u_inf, v_inf)`` the pixel of the ray's direction at infinity and ``a = f_r (o_xy - o_z w_xy / w_z)`` (px m).
    The four fields are computed once per (rays, ``K_r``) in float64 and kept in float32 for the iteration (their
    rounding, < 1e-4 render px, is far below the 1/32 px bilinear weight quantisation of ``cv2.remap``).
    """

    u_inf: np.ndarray  # (R, C) float64
    v_inf: np.ndarray
    a_u: np.ndarray
    a_v: np.ndarray
    o_z: np.ndarray  # (R, C) float64
    w_z: np.ndarray
    f32: tuple  # float32 copies of (u_inf, v_inf, a_u, a_v, o_z) and max(|a_u|, |a_v|)

    def rows(self, r0: int, r1: int) -> _RayProjection:
        """The rays of grid rows ``r0..r1`` (views)."""
        return _RayProjection(*(a[r0:r1] for a in (self.u_inf, self.v_inf, self.a_u, self.a_v, self.o_z, self.w_z)),
                              tuple(a[r0:r1] for a in self.f32))

    @classmethod
    def build(cls, o, w, K_r) -> _RayProjection:
        rx, ry = w[..., 0] / w[..., 2], w[..., 1] / w[..., 2]
        u_inf = K_r[0, 0] * rx + K_r[0, 2]
        v_inf = K_r[1, 1] * ry + K_r[1, 2]
        a_u = K_r[0, 0] * (o[..., 0] - o[..., 2] * rx)
        a_v = K_r[1, 1] * (o[..., 1] - o[..., 2] * ry)
        o_z, w_z = np.ascontiguousarray(o[..., 2]), np.ascontiguousarray(w[..., 2])
        f32 = tuple(np.ascontiguousarray(a, dtype=np.float32)
                    for a in (u_inf, v_inf, a_u, a_v, o_z, np.maximum(np.abs(a_u), np.abs(a_v))))
        return cls(u_inf, v_inf, a_u, a_v, o_z, w_z, f32)


def _converged(z, z_new, o_z, a_max, tol_rel, tol_px):
    """``|dz| <= tol_rel |z - o_z|``, or the sample point moved by at most ``tol_px`` render px (when > 0)."""
    dz = np.abs(z_new - z)
    conv = dz <= np.float32(tol_rel) * np.abs(z - o_z)
    if tol_px > 0:  # |du| = |a_u| |1/z_new - 1/z| = |a_u| |dz| / (z z_new)
        conv |= a_max * dz <= np.float32(tol_px) * z * z_new
    return conv


def _remap_points(src, u, v):
    """Bilinear ``cv2.remap`` of a single-channel float32 image at the points ``(u, v)`` (flat float32 arrays)."""
    n = u.size
    cols = 1024
    rows = -(-n // cols)
    mu = np.zeros(rows * cols, np.float32)
    mv = np.zeros(rows * cols, np.float32)
    mu[:n], mv[:n] = u, v
    out = cv2.remap(src, mu.reshape(rows, cols), mv.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1)[:n]


def _depth_fixed_point(proj: _RayProjection, depth32, max_iterations: int, tol_rel: float, tol_px: float = 0.0):
    """The depth fixed point of :class:`FlatPortStage` for a grid of rays: ``(lam, u, v, status)``, each ``(R, C)``.

    In the point's z (see :class:`_RayProjection`) the iteration ``lambda <- (z_r(K_r pi(o + lambda w)) - o_z) /
    w_z`` reads ``z <- z_r(u(z), v(z))``, started from the render depth in the ray's far direction; a ray has
    converged when ``|dz| <= tol_rel (z - o_z)`` (i.e. ``|d lambda| <= tol_rel lambda``) or, with ``tol_px > 0``,
    when its sample point moves by at most ``tol_px`` render px (``max(|a_u|, |a_v|) |d(1/z)| <= tol_px``). Each
    step samples the depth buffer (bilinear, ``cv2.remap``) for the whole grid while many rays are active, then for
    the remaining rays only. status: 0 converged on a finite surface, 1 background (infinite depth in the far
    direction), 2 not converged (an occlusion edge) or stepped onto the background. ``(u, v)`` (render px, float32:
    the maps of ``cv2.remap``, whose rounding, < 1e-4 px, is far below its 1/32 px weight quantisation) is the
    converged point's pixel for status 0 and the direction at infinity otherwise; ``lam`` (float64) is inf unless
    status is 0.
    """
    u_inf, v_inf, a_u, a_v, o_z, a_max = proj.f32
    shape = u_inf.shape
    z = cv2.remap(depth32, u_inf, v_inf, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    status = np.full(shape, 2, dtype=np.int8)
    active = np.isfinite(z)
    status[~active] = 1
    n_total = z.size
    it = 0
    while it < max_iterations and np.count_nonzero(active) > _DENSE_FRACTION * n_total:  # dense steps
        it += 1
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.float32(1.0) / z
            z_new = cv2.remap(depth32, u_inf + a_u * inv, v_inf + a_v * inv, cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
            fin = np.isfinite(z_new)
            conv = active & fin & _converged(z, z_new, o_z, a_max, tol_rel, tol_px)
        np.copyto(z, z_new, where=active & fin)
        status[conv] = 0
        active &= fin & ~conv
    idx = np.flatnonzero(active)
    zf, sf = z.reshape(-1), status.reshape(-1)
    if idx.size and it < max_iterations:  # sparse steps on the remaining rays
        ui, vi, aui, avi, ozi, ami = (a.reshape(-1)[idx] for a in (u_inf, v_inf, a_u, a_v, o_z, a_max))
        zi = zf[idx]
        for _ in range(it, max_iterations):
            inv = np.float32(1.0) / zi
            z_new = _remap_points(depth32, ui + aui * inv, vi + avi * inv)
            fin = np.isfinite(z_new)
            conv = fin & _converged(zi, z_new, ozi, ami, tol_rel, tol_px)
            zi = np.where(fin, z_new, zi)
            sf[idx[conv]] = 0
            keep = fin & ~conv
            zf[idx] = zi
            idx, zi, ui, vi, aui, avi, ozi, ami = (a[keep] for a in (idx, zi, ui, vi, aui, avi, ozi, ami))
            if idx.size == 0:
                break
    hit = status == 0
    inv = np.where(hit, np.float32(1.0) / z, np.float32(0.0))
    u, v = u_inf + a_u * inv, v_inf + a_v * inv
    lam = np.where(hit, (z.astype(np.float64) - proj.o_z) / proj.w_z, np.inf)
    return lam, u, v, status
