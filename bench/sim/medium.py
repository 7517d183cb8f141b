"""The water medium and the image sensor: what water, a lamp and a camera sensor do to a rendered image.

All images here are linear radiance in ``[0, 1]`` (a uint8 render is divided by 255 and treated as linear), channels in
RGB order, shape ``(H, W, 3)``; path lengths in m; every parameter is SI with the unit in its name. Stages, each usable
on its own and applied in this order by :func:`apply_medium`:

1. :func:`illuminate` - a lamp co-located with the camera or offset (:func:`lamp_geometry`):
   ``E = ambient + (r_ref / r)^2 cos^k(theta)`` (inverse square in the lamp-to-point range, a ``cos^k`` beam profile
   about the lamp's axis), optionally attenuated on its way out (``exp(-beta_D r)``);
2. :func:`attenuate` - the revised underwater image formation model of Akkaynak & Treibitz (CVPR 2018, "A revised
   underwater image formation model"; Sea-thru, CVPR 2019), with distinct coefficients for the direct signal and the
   backscatter: ``I_c = J_c exp(-beta_D_c r) + B_inf_c (1 - exp(-beta_B_c r))`` per channel ``c``; ``r`` is the path
   length in water along the pixel's ray. For a pinhole render it comes from the z-depth map:
   ``r = z |ray| / ray_z`` (:func:`path_length_m`); the flat-port stage returns it directly
   (:attr:`bench.sim.flatport.FlatPortImage.water_path`, from the outer glass surface);
3. :func:`forward_scatter` - small-angle scattering as a depth-dependent Gaussian blur, ``sigma = c r`` px (capped);
4. :func:`sensor` - photo-electrons (Poisson shot noise, full-well capacity), Gaussian read noise in electrons, gain
   in DN per electron, 8-bit quantisation; :func:`jpeg` optional compression (``quality = 0`` is off).

Noise is drawn from an explicit ``numpy.random.Generator``: the same seed gives the same image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from bench.camera.model import check_K
from bench.sim.parallel import band_edges, map_bands

# ----------------------------------------------------------------------------------------------------------------------
# parameters
# ----------------------------------------------------------------------------------------------------------------------


def _vec3(owner, key, value, lo=0.0, hi=np.inf):
    arr = np.array(value, dtype=float).reshape(-1) if np.ndim(value) else np.full(3, float(value))
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or np.any(arr < lo) or np.any(arr > hi):
        raise ValueError(f"{owner}: {key}: expected 3 finite values (R, G, B) in [{lo:g}, {hi:g}], got {value!r}")
    arr.flags.writeable = False
    return arr


def _scalar(owner, key, value, lo=0.0, hi=np.inf, lo_open=False):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value) or value < lo or value > hi or (lo_open and value == lo):
        bound = f"({lo:g}" if lo_open else f"[{lo:g}"
        raise ValueError(f"{owner}: {key}: expected a finite number in {bound}, {hi:g}], got {value!r}")
    return float(value)


@dataclass(frozen=True)
class WaterMedium:
    """Per-channel (R, G, B) optical coefficients of a water body (Akkaynak & Treibitz's revised model).

    Attributes
    ----------
    beta_D_per_m : (3,) float
        Attenuation coefficient of the direct signal (1/m).
    beta_B_per_m : (3,) float
        Backscatter coefficient (1/m).
    B_inf : (3,) float
        Veiling light (backscatter at infinite range), linear radiance in [0, 1].
    forward_scatter_px_per_m : float
        Forward-scatter blur: Gaussian sigma (output px) per metre of path.
    name : str
    """

    beta_D_per_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    beta_B_per_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    B_inf: np.ndarray = field(default_factory=lambda: np.zeros(3))
    forward_scatter_px_per_m: float = 0.0
    name: str = "water"

    def __post_init__(self):
        src = f"medium {self.name!r}"
        object.__setattr__(self, "beta_D_per_m", _vec3(src, "beta_D_per_m", self.beta_D_per_m, 0.0, 50.0))
        object.__setattr__(self, "beta_B_per_m", _vec3(src, "beta_B_per_m", self.beta_B_per_m, 0.0, 50.0))
        object.__setattr__(self, "B_inf", _vec3(src, "B_inf", self.B_inf, 0.0, 1.0))
        object.__setattr__(self, "forward_scatter_px_per_m",
                           _scalar(src, "forward_scatter_px_per_m", self.forward_scatter_px_per_m, 0.0, 100.0))


#: Water presets, broadband camera RGB (R ~ 600, G ~ 525, B ~ 475 nm). The attenuation values are rounded,
#: approximate broadband coefficients for Jerlov water types (Jerlov, "Marine Optics", 1976; the IOPs of the types in
#: Solonenko & Mobley, Appl. Opt. 54(17), 2015) in the ranges that Akkaynak et al., "What is the space of attenuation
#: coefficients in underwater computer vision?", CVPR 2017, report for consumer cameras: clear ocean = Jerlov I,
#: coastal = Jerlov 3C, turbid harbour = Jerlov 9C. beta_B and B_inf are of the same order as Sea-thru's estimates
#: (Akkaynak & Treibitz, CVPR 2019) and the forward-scatter blur is a bench choice: illustrative values, not a
#: measurement of a particular site.
WATER_PRESETS = {
    "clear_ocean": dict(beta_D_per_m=(0.35, 0.07, 0.04), beta_B_per_m=(0.30, 0.10, 0.08), B_inf=(0.02, 0.12, 0.25),
                        forward_scatter_px_per_m=0.1),
    "coastal": dict(beta_D_per_m=(0.55, 0.30, 0.40), beta_B_per_m=(0.55, 0.35, 0.45), B_inf=(0.05, 0.22, 0.20),
                    forward_scatter_px_per_m=0.4),
    "turbid_harbour": dict(beta_D_per_m=(1.10, 0.90, 1.40), beta_B_per_m=(1.20, 1.00, 1.40),
                           B_inf=(0.12, 0.25, 0.18), forward_scatter_px_per_m=1.2),
}


def water_preset(name: str) -> WaterMedium:
    """The :class:`WaterMedium` of a preset; unknown name -> one-line ``ValueError`` listing the known ones."""
    if not isinstance(name, str) or name not in WATER_PRESETS:
        raise ValueError(f"water preset: unknown {name!r} (known: {', '.join(sorted(WATER_PRESETS))})")
    return WaterMedium(name=name, **WATER_PRESETS[name])


@dataclass(frozen=True)
class Light:
    """A lamp (co-located with the camera centre by default, or offset) plus ambient light.

    Attributes
    ----------
    ref_range_m : float
        Range (m) at which the lamp's on-axis irradiance factor is 1 (``(ref_range_m / r)^2``).
    beam_exponent : float
        ``k`` of the ``cos^k(theta)`` beam profile about the lamp's axis (0 = isotropic).
    ambient : float
        Ambient irradiance factor added everywhere (>= 0).
    attenuate_outgoing : bool
        Also attenuate the lamp's light on its way to the scene (``exp(-beta_D r)``, needs a medium).
    position_m : (3,) float
        Lamp position in the camera frame (m); ``(0, 0, 0)`` is co-located.
    axis : (3,) float
        Beam axis in the camera frame (normalised here); default the optical axis ``(0, 0, 1)``.
    """

    ref_range_m: float = 1.0
    beam_exponent: float = 2.0
    ambient: float = 0.0
    attenuate_outgoing: bool = True
    position_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def __post_init__(self):
        object.__setattr__(self, "ref_range_m", _scalar("light", "ref_range_m", self.ref_range_m, 0.0, 1e3, True))
        object.__setattr__(self, "beam_exponent", _scalar("light", "beam_exponent", self.beam_exponent, 0.0, 1e3))
        object.__setattr__(self, "ambient", _scalar("light", "ambient", self.ambient, 0.0, 1e3))
        object.__setattr__(self, "position_m", _vec3("light", "position_m", self.position_m, -10.0, 10.0))
        axis = np.array(self.axis, dtype=float).reshape(-1)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or np.linalg.norm(axis) < 1e-9:
            raise ValueError(f"light: axis: expected a non-zero finite 3-vector, got {self.axis!r}")
        axis = axis / np.linalg.norm(axis)
        axis.flags.writeable = False
        object.__setattr__(self, "axis", axis)

    @property
    def co_located(self) -> bool:
        """True when the lamp sits at the camera centre and points along the optical axis."""
        return bool(np.all(self.position_m == 0) and np.allclose(self.axis, (0.0, 0.0, 1.0), rtol=0, atol=1e-15))


#: Rec. 601 luma weights of R, G, B (the metering of the automatic exposure, the luma a camera sharpens)
REC601_LUMA = np.array([0.299, 0.587, 0.114], np.float32)


@dataclass(frozen=True)
class Sensor:
    """Image sensor: shot noise on electrons, read noise, gain, 8-bit output, optional JPEG.

    Attributes
    ----------
    full_well_e : float
        Electrons collected for linear radiance 1 at ``exposure = 1`` (and the clipping level).
    exposure : float
        Scale from linear radiance to the fraction of full well.
    gain_dn_per_e : float
        Digital numbers per electron (``255 / full_well_e`` maps full well to 255).
    read_noise_e : float
        Standard deviation of the Gaussian read noise (electrons).
    jpeg_quality : int
        0 = lossless 8-bit output, 1..100 = JPEG re-encoding with ``cv2.imencode`` at that quality.
    auto_exposure_target : float
        0 (default): manual exposure, ``exposure`` is used as given. In (0, 1]: automatic exposure, as machine-vision
        and ROV cameras run it (the camera adjusts its exposure time per frame until the mean grey value reaches a
        target given as a fraction of the maximum: e.g. FLIR Spinnaker's "target grey value", 50 % -> a histogram
        mean of 128 DN at 8 bit; Basler's "Exposure Auto" adjusts the exposure time within limits to a target
        brightness): each image is metered - the mean Rec. 601 luma ``0.299 R + 0.587 G + 0.114 B`` of its linear
        radiance over the whole frame (average metering) - and exposed with
        ``exposure = min(auto_exposure_target / mean, auto_exposure_max)``, so that its mean signal is the target
        fraction of full well. The exposure *time* changes (more electrons, less relative shot noise), not the gain.
    auto_exposure_max : float
        Longest exposure the automatic exposure may choose (in units of ``exposure = 1``; the limit a moving ROV
        camera has against motion blur).
    digitiser_px : tuple of int or None
        None (default): a digital camera, its output at the camera's resolution. ``(w, h)``: an analog video camera
        whose signal a frame grabber samples at ``w x h`` pixels, the frames then interpolated to the camera's
        resolution (the thesis's MCH-3000P through a Pinnacle PCTV card at 320 x 240, cubic-spline interpolated to
        640 x 480 in Matlab, section 5.3). Applied by the realistic imaging profile's ``frame_grabber`` stage
        (:func:`bench.sim.imaging.frame_grab`); the ideal chain leaves it out.
    """

    full_well_e: float = 10000.0
    exposure: float = 1.0
    gain_dn_per_e: float = 255.0 / 10000.0
    read_noise_e: float = 5.0
    jpeg_quality: int = 0
    auto_exposure_target: float = 0.0
    auto_exposure_max: float = 16.0
    digitiser_px: tuple | None = None

    def __post_init__(self):
        object.__setattr__(self, "full_well_e", _scalar("sensor", "full_well_e", self.full_well_e, 1.0, 1e8))
        object.__setattr__(self, "exposure", _scalar("sensor", "exposure", self.exposure, 0.0, 1e6, True))
        object.__setattr__(self, "gain_dn_per_e", _scalar("sensor", "gain_dn_per_e", self.gain_dn_per_e, 0.0, 1e3,
                                                          True))
        object.__setattr__(self, "read_noise_e", _scalar("sensor", "read_noise_e", self.read_noise_e, 0.0, 1e6))
        q = self.jpeg_quality
        if isinstance(q, bool) or not isinstance(q, (int, np.integer)) or not 0 <= q <= 100:
            raise ValueError(f"sensor: jpeg_quality: expected an integer in 0..100 (0 = off), got {q!r}")
        object.__setattr__(self, "jpeg_quality", int(q))
        object.__setattr__(self, "auto_exposure_target",
                           _scalar("sensor", "auto_exposure_target", self.auto_exposure_target, 0.0, 1.0))
        object.__setattr__(self, "auto_exposure_max",
                           _scalar("sensor", "auto_exposure_max", self.auto_exposure_max, 0.0, 1e6, True))
        d = self.digitiser_px
        if d is not None:
            if (isinstance(d, (str, bytes)) or not hasattr(d, "__len__") or len(d) != 2
                    or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and 8 <= v <= 100000
                               for v in d)):
                raise ValueError(f"sensor: digitiser_px: expected two whole pixel counts (w, h) >= 8, got {d!r}")
            object.__setattr__(self, "digitiser_px", (int(d[0]), int(d[1])))

    def exposure_for(self, image, target: float | None = None) -> float:
        """The exposure used for linear radiance ``image (H, W, 3)``: ``exposure``, or the automatic exposure that
        brings the mean linear luma to ``target`` (default ``auto_exposure_target``; a camera whose output is
        gamma-encoded passes the linear level of its output target)."""
        if self.auto_exposure_target == 0:
            return self.exposure
        target = self.auto_exposure_target if target is None else target
        luma = float(np.tensordot(np.asarray(image), REC601_LUMA, axes=([-1], [0])).mean(dtype=np.float64))
        if luma <= target / self.auto_exposure_max:
            return self.auto_exposure_max
        return target / luma


# ----------------------------------------------------------------------------------------------------------------------
# checks and geometry
# ----------------------------------------------------------------------------------------------------------------------
def check_image(image, name="image") -> np.ndarray:
    """Linear radiance ``(H, W, 3)``: uint8 is divided by 255 (float64), floats must be finite and >= 0.

    float32 stays float32 (what :func:`apply_medium` computes in: its relative rounding, 6e-8, is 1e-3 electron at
    full well), other floats become float64.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"{name}: expected an RGB image (H, W, 3), got shape {img.shape}")
    if img.dtype == np.uint8:
        return img.astype(float) / 255.0
    if img.dtype.kind != "f":
        raise ValueError(f"{name}: expected uint8 or float radiance, got dtype {img.dtype}")
    img = img if img.dtype == np.float32 else img.astype(float)
    if not np.isfinite(img).all() or (img < 0).any():
        raise ValueError(f"{name}: float radiance must be finite and >= 0")
    return img


def check_path(path_m, shape, name="path_m") -> np.ndarray:
    """Path lengths ``(H, W)`` (m): >= 0, inf allowed (background), no NaN."""
    r = np.asarray(path_m, dtype=float)
    if r.shape != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got {r.shape}")
    if np.any(np.isnan(r)) or np.any(r < 0):
        raise ValueError(f"{name}: must be >= 0 m (inf for background), no NaN")
    return r


def pixel_rays(K, size) -> np.ndarray:
    """Rays ``(H, W, 3)`` with ``z = 1`` through the pixel centres of a pinhole camera (Eq. 51)."""
    K = check_K(K)
    W, H = (int(v) for v in size)
    uu, vv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    y = (vv - K[1, 2]) / K[1, 1]
    x = (uu - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x, y, np.ones_like(x)], -1)


def path_length_m(depth_z_m, rays_cam) -> np.ndarray:
    """Path length along each pixel's ray to the point of z-depth ``z``: ``r = z |ray| / ray_z`` (m).

    Parameters
    ----------
    depth_z_m : array_like (H, W)
        z-depth (m, along the optical axis); inf for background.
    rays_cam : array_like (H, W, 3)
        The pixel rays (any length, ``ray_z > 0``), e.g. :func:`pixel_rays`.
    """
    z = np.asarray(depth_z_m, dtype=float)
    rays = np.asarray(rays_cam, dtype=float)
    if rays.shape != z.shape + (3,):
        raise ValueError(f"rays_cam: expected shape {z.shape + (3,)}, got {rays.shape}")
    if np.any(rays[..., 2] <= 0):
        raise ValueError("rays_cam: every ray must point forward (z > 0)")
    check_path(z, z.shape, "depth_z_m")
    return z * np.linalg.norm(rays, axis=-1) / rays[..., 2]


def cos_beam(rays_cam) -> np.ndarray:
    """Cosine of each ray's angle to the optical axis (the lamp's axis), ``(H, W)``."""
    rays = np.asarray(rays_cam, dtype=float)
    return rays[..., 2] / np.linalg.norm(rays, axis=-1)


def lamp_geometry(points_cam, light: Light):
    """Range (m) from the lamp to each scene point and the cosine of its angle off the beam axis.

    Parameters
    ----------
    points_cam : array_like (H, W, 3)
        Scene points in the camera frame (m); rows with a non-finite coordinate (background) get range inf, cos 0.
    light : Light

    Returns
    -------
    range_m : ndarray (H, W)
    cos_theta : ndarray (H, W)
        Clipped to [0, 1] (points behind the lamp get no lamp light).
    """
    p = np.asarray(points_cam, dtype=float)
    if p.ndim != 3 or p.shape[2] != 3:
        raise ValueError(f"points_cam: expected shape (H, W, 3), got {p.shape}")
    if np.any(np.isnan(p)):
        raise ValueError("points_cam: contains NaN (use inf for background)")
    fin = np.all(np.isfinite(p), axis=-1)
    v = np.where(fin[..., None], p - light.position_m, light.axis)
    r = np.linalg.norm(v, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(r > 0, (v @ light.axis) / r, 1.0)
    return np.where(fin, r, np.inf), np.where(fin, np.clip(c, 0.0, 1.0), 0.0)


# ----------------------------------------------------------------------------------------------------------------------
# the stages
# ----------------------------------------------------------------------------------------------------------------------
def illuminate(image, range_m, cos_theta, light: Light, medium: WaterMedium | None = None) -> np.ndarray:
    """Scene radiance lit by the lamp: ``J (ambient + (r_ref / r)^2 cos^k(theta) [exp(-beta_D r)])``.

    Parameters
    ----------
    image : array_like (H, W, 3)
        Reflectance-like render (linear).
    range_m : array_like (H, W)
        Distance (m) from the lamp to the point; inf = background (no lamp light).
    cos_theta : array_like (H, W)
        Cosine of the angle off the lamp's axis (:func:`cos_beam` for a co-located lamp, else :func:`lamp_geometry`).
    light : Light
    medium : WaterMedium, optional
        Attenuates the outgoing light when ``light.attenuate_outgoing``.
    """
    J = check_image(image)
    dt = J.dtype
    r = check_path(range_m, J.shape[:2], "range_m").astype(dt, copy=False)
    c = np.asarray(cos_theta)
    if c.shape != r.shape or not np.isfinite(c).all() or (c < 0).any() or (c > 1).any():
        raise ValueError(f"cos_theta: expected values in [0, 1] with shape {r.shape}")
    with np.errstate(divide="ignore"):
        lamp = (dt.type(light.ref_range_m) / r) ** 2 * c.astype(dt, copy=False) ** dt.type(light.beam_exponent)
    lamp = np.where(r > 0, lamp, dt.type(0))[..., None]
    if medium is not None and light.attenuate_outgoing:
        lamp = lamp * np.exp(-medium.beta_D_per_m.astype(dt) * r[..., None])
    return J * (dt.type(light.ambient) + lamp)


def attenuate(image, path_m, medium: WaterMedium) -> np.ndarray:
    """``I_c = J_c exp(-beta_D_c r) + B_inf_c (1 - exp(-beta_B_c r))`` (Akkaynak & Treibitz 2018, revised model).

    ``path_m`` is the in-water path length along each pixel's ray (m); inf gives the veiling light ``B_inf``.
    """
    J = check_image(image)
    dt = J.dtype
    r = check_path(path_m, J.shape[:2]).astype(dt, copy=False)[..., None]
    far = np.isinf(r)
    direct = np.where(far, dt.type(0), J * np.exp(-medium.beta_D_per_m.astype(dt) * np.where(far, dt.type(0), r)))
    return direct + medium.B_inf.astype(dt) * (dt.type(1) - np.exp(-medium.beta_B_per_m.astype(dt) * r))


def forward_scatter(image, path_m, sigma_px_per_m: float, max_sigma_px: float = 3.0, levels: int = 7):
    """Depth-dependent Gaussian blur ``sigma = min(sigma_px_per_m r, max_sigma_px)`` (px).

    The image is blurred at ``levels`` sigmas evenly spaced in ``[0, max]`` and each pixel interpolates linearly
    between the two levels around its sigma (a zero path leaves a pixel unchanged): the weight of level ``l`` is the
    hat ``max(0, 1 - |sigma / step - l|)``, so only the levels up to the largest sigma in the image are blurred.
    """
    img = check_image(image)
    r = check_path(path_m, img.shape[:2])
    sigma_px_per_m = _scalar("forward_scatter", "sigma_px_per_m", sigma_px_per_m, 0.0, 100.0)
    max_sigma_px = _scalar("forward_scatter", "max_sigma_px", max_sigma_px, 0.0, 50.0, True)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 2:
        raise ValueError(f"levels: expected an integer >= 2, got {levels!r}")
    with np.errstate(invalid="ignore"):
        sig = np.minimum(sigma_px_per_m * r, max_sigma_px)
    sig = np.where(np.isnan(sig), 0.0, sig)  # 0 * inf
    if not np.any(sig > 0):
        return img
    step = max_sigma_px / (levels - 1)
    pos = (sig / step).astype(img.dtype)
    top = min(int(np.ceil(pos.max())), levels - 1)  # the highest level with a non-zero weight
    out = np.zeros_like(img)
    for lev in range(top + 1):
        wgt = np.maximum(img.dtype.type(0), img.dtype.type(1) - np.abs(pos - lev))
        if not wgt.any():
            continue
        g = lev * step
        blurred = img if lev == 0 else cv2.GaussianBlur(img, (0, 0), sigmaX=g, sigmaY=g,
                                                        borderType=cv2.BORDER_REFLECT)
        out += wgt[..., None] * blurred
    return out


#: Shot noise of pixels collecting at least this many electrons is drawn from its normal limit: Poisson(E) + N(0, r^2)
#: -> N(E, E + r^2) in one draw (4x faster than numpy's Poisson sampler). The difference of the two distributions is
#: the Poisson skewness E^-1/2 <= 0.032 here: their CDFs differ by at most ~0.066 / sqrt(E) <= 0.002 (the first
#: Edgeworth term), while one DN holds ~40 e- at the default gain - not measurable in any image statistic (tested
#: against exact Poisson draws). Darker pixels get exact Poisson counts.
SHOT_NOISE_NORMAL_ABOVE_E = 1000.0


def sensor(image, rng: np.random.Generator, spec: Sensor) -> np.ndarray:
    """8-bit image of linear radiance: ``DN = round(gain (Poisson(min(E, full well)) + N(0, read^2)))``.

    ``E = image * exposure * full_well_e`` electrons (``exposure`` from :meth:`Sensor.exposure_for`: the given one or
    the automatic exposure); DN clipped to 0..255; then JPEG if ``spec.jpeg_quality``. Images of at least
    :data:`bench.sim.parallel.MIN_ROWS` rows are drawn in row bands, in parallel threads, each from its own child
    generator (``rng.spawn``): the image of a seed is the same on every machine. Shot noise above
    :data:`SHOT_NOISE_NORMAL_ABOVE_E` electrons is drawn from its normal limit.
    """
    img = check_image(image)
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    edges = band_edges(img.shape[0])
    rngs = [rng] if len(edges) == 2 else rng.spawn(len(edges) - 1)
    scale = spec.exposure_for(img) * spec.full_well_e

    def band(r0, r1):
        g = rngs[0] if len(rngs) == 1 else rngs[int(np.searchsorted(edges, r0))]
        # electron counts are integers below 1e8 and the read noise a few e-: float32 holds both exactly enough
        lam = np.minimum(img[r0:r1] * scale, spec.full_well_e).astype(np.float32)
        z = g.standard_normal(lam.shape, dtype=np.float32)
        read = np.float32(spec.read_noise_e)
        e = lam + np.sqrt(lam + read * read) * z  # shot + read noise, normal limit
        low = lam < SHOT_NOISE_NORMAL_ABOVE_E
        if low.any():  # exact Poisson counts (z, independent of them, is the read noise)
            e[low] = g.poisson(lam[low]).astype(np.float32) + read * z[low]
        e *= np.float32(spec.gain_dn_per_e)
        return np.clip(np.rint(e), 0, 255).astype(np.uint8)

    parts = map_bands(band, edges)
    out = parts[0] if len(parts) == 1 else np.concatenate(parts)
    return jpeg(out, spec.jpeg_quality)


def encode_jpeg(image_u8, quality: int) -> bytes:
    """JPEG bytes of an RGB uint8 image ``(H, W, 3)`` at ``quality`` (1..100) with ``cv2.imencode``."""
    img = np.asarray(image_u8)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image_u8: expected uint8 (H, W, 3), got {img.dtype} {img.shape}")
    if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or not 1 <= quality <= 100:
        raise ValueError(f"quality: expected an integer in 1..100, got {quality!r}")
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("image_u8: JPEG encoding failed")
    return buf.tobytes()


def jpeg(image_u8, quality: int) -> np.ndarray:
    """JPEG round trip of an RGB uint8 image at ``quality`` (1..100) with ``cv2.imencode``; 0 returns it unchanged."""
    img = np.asarray(image_u8)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image_u8: expected uint8 (H, W, 3), got {img.dtype} {img.shape}")
    if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or not 0 <= quality <= 100:
        raise ValueError(f"quality: expected an integer in 0..100 (0 = off), got {quality!r}")
    if quality == 0:
        return img
    buf = np.frombuffer(encode_jpeg(img, quality), dtype=np.uint8)
    return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])


@dataclass(frozen=True)
class MediumChain:
    """The medium and sensor stages with their parameters (any of ``medium``/``light``/``sensor`` may be None)."""

    medium: WaterMedium | None = None
    light: Light | None = None
    sensor: Sensor | None = None
    max_blur_px: float = 3.0


def apply_medium(image, path_m, rng: np.random.Generator, chain: MediumChain, cos_theta=None, points_cam=None):
    """Illuminate, attenuate + backscatter, forward-scatter, then the sensor (see the module docstring).

    Parameters
    ----------
    image : array_like (H, W, 3)
        The render (uint8 or linear float).
    path_m : array_like (H, W)
        In-water path length (m) per pixel (inf = background). Without ``points_cam`` it is also the lamp range of a
        co-located lamp (the few cm between the camera centre and the port are neglected for the lamp).
    rng : numpy.random.Generator
    chain : MediumChain
    cos_theta : array_like (H, W), optional
        Beam profile cosines of a co-located lamp (:func:`cos_beam`); required when ``chain.light`` is set and
        ``points_cam`` is not given.
    points_cam : array_like (H, W, 3), optional
        The scene point of each pixel (m, camera frame; inf = background): the lamp range and beam angle are then
        computed from the lamp's position and axis (:func:`lamp_geometry`); required for an offset lamp.

    Returns
    -------
    ndarray (H, W, 3)
        uint8 when ``chain.sensor`` is set, else linear float64. (A uint8 render is processed in float32.)
    """
    img = np.asarray(image)
    img = (img.astype(np.float32) * np.float32(1 / 255)) if img.dtype == np.uint8 else check_image(img)
    r = check_path(path_m, img.shape[:2])
    r_lamp = None
    if chain.light is not None:
        if points_cam is not None:
            r_lamp, cos_theta = lamp_geometry(points_cam, chain.light)
            if r_lamp.shape != r.shape:
                raise ValueError(f"points_cam: expected shape {r.shape + (3,)}, got {np.shape(points_cam)}")
        elif not chain.light.co_located:
            raise ValueError("points_cam: needed for a lamp that is not co-located with the camera (lamp_geometry)")
        elif cos_theta is None:
            raise ValueError("cos_theta: needed for the lamp's beam profile (see cos_beam)")
        else:
            r_lamp = r
    if r_lamp is not None or chain.medium is not None:

        def lit(r0, r1):  # per-pixel stages, in row bands
            out = img[r0:r1]
            if r_lamp is not None:
                out = illuminate(out, r_lamp[r0:r1], np.asarray(cos_theta)[r0:r1], chain.light, chain.medium)
            if chain.medium is not None:
                out = attenuate(out, r[r0:r1], chain.medium)
            return out

        parts = map_bands(lit, band_edges(img.shape[0]))
        img = parts[0] if len(parts) == 1 else np.concatenate(parts)
    if chain.medium is not None:
        if chain.medium.forward_scatter_px_per_m > 0:
            img = forward_scatter(img, r, chain.medium.forward_scatter_px_per_m, chain.max_blur_px)
    if chain.sensor is not None:
        return sensor(img, rng, chain.sensor)
    return img.astype(np.float64)
