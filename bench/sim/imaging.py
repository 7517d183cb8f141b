"""Imaging profiles: how a real camera and a real target err beyond the ideal render (issue 12).

``imaging: ideal`` is the bench's clean chain (supersampled pinhole render -> lens stage -> medium -> sensor noise).
``imaging: realistic`` (the default of every rendering kind) adds the error sources a real camera and a real
calibration target have, each a physical model with its parameters in SI-derived units and its source stated, each
switchable on its own (``camera.imaging_off: [jpeg, defocus, ...]``, :data:`STAGES`):

Target (applied to the rig's geometry, :func:`target_geometry`, never to the image):

* ``print_lines`` - the printed pattern's row and column lines are not evenly spaced: a printer's paper feed
  advances unevenly (banding), so each row line of corners is offset along the feed by a random amount (rms
  ``feed_rms_mm``), each column line across the feed by another (``scan_rms_mm``). Measured on the real webcam
  photos together with the board's 3-D shape (tools/real_camera_stats.py ``measure_board_shape``:
  ``shape_print_row_offsets_rms_mm`` 0.09 mm, ``shape_print_col_offsets_rms_mm`` 0.05 mm for a 25 mm square; the
  0.28 mm of an in-plane-only fit was mostly the cockle below seen from tilted views);
* ``print_scale`` - the printout's scale differs from the file's (``scale_rms_pct``; office printers ~0.1-0.3 %);
* ``toner`` - the printed black's reflectance (``black_reflectance``; the white's is 0.92): 0.018, fitted with the
  tone stage below to the real photos' black squares (38 DN) and edge profiles (docs/realistic_imaging.md section
  1.1); the ideal scene's is 0.03;
* ``flatness`` - paper on a board is not flat: a cylindrical bow of sagitta ``bow_sagitta_mm`` (random sign) across
  each board (real photos: quadratic bow fit, median 0.6 mm, an upper bound);
* ``cockle`` - printed paper is wavy on a smaller scale too (cockle): out-of-plane offsets at every line crossing,
  a zero-mean Gaussian random field with covariance ``rms^2 exp(-dx^2 / (2 Lx^2) - dy^2 / (2 Ly^2))`` (``Lx``
  along the rows, ``Ly`` across them), fixed for the board. Measured on the real webcam photos: 93 % of their
  calibration residual lies along the image direction in which an out-of-plane offset moves each corner (50 % for
  isotropic errors), the per-view RMS follows that direction's sensitivity (correlation 0.77), and a 3-D board shape
  common to all 19 views (OpenCV's release-object calibration) takes the RMS from 0.557 to 0.219 px; that shape,
  its quadratic bow removed, is fitted by restricted maximum likelihood: ``rms_mm`` 0.42, ``Lx`` 25 mm, ``Ly``
  17 mm (``cockle_*`` in tools/real_camera_stats.py);
* ``handling`` - a hand-held board also flexes, differently in each photo: per view, another Gaussian field of
  out-of-plane offsets (:func:`handling_dz`). Measured on the real webcam photos: what is left once the common
  shape is estimated (0.219 px) still lies 82 % along the out-of-plane direction; its per-view offsets, each view's
  plane removed, fitted jointly by restricted maximum likelihood: ``rms_mm`` 0.25, ``Lx`` 22 mm, ``Ly`` 19 mm
  (``handling_*``).
  Only a board that is handled between photos has it (the real-photo simulation, the ``camera_replica`` scenario kind);
  the two-plane rig of the lab kinds stands still while the camera moves, so there the stage changes nothing;
* ``fold`` - the two boards of the rig are not exactly perpendicular (``fold_error_rms_deg``; a hand-assembled rig).

Optics (applied to the image at the camera's resolution, in linear radiance):

* ``distortion`` - lens distortion the ideal chain leaves out: the true lens gets the real webcam's measured radial
  distortion (:data:`WEBCAM_DISTORTION`, k1 and k2) plus a thin prism (Weng, Cohen & Herniou, PAMI 14(10) 1992:
  ``s1 r^2, s3 r^2``) applied as an image warp;
* ``chromatic`` - lateral chromatic aberration: R and B magnified by ``1 + c`` about the principal point (real
  photos: |c| < 1e-4, kept at the measured value);
* ``defocus`` - thin-lens circle of confusion (:func:`coc_diameter_px`) from focal length, f-number and focus
  distance at each pixel's depth (a pillbox PSF), plus the lens's residual optical blur (a Gaussian, ``lens_sigma_px``:
  diffraction ``0.42 lambda N`` and aberrations, set so that the whole chain's edge spread matches the real photos'
  0.46 px);
* ``motion`` - camera shake during the exposure: a random angular rate (rms ``angular_rate_rms_deg_per_s`` per axis)
  moves the image by ``f omega`` px/s, a line blur over ``exposure_s``;
* ``rolling_shutter`` - row ``r`` is exposed ``(r - H/2) readout_s / H`` after the middle row: the same image
  velocity displaces it by that time (:func:`row_times_s`);
* ``vignetting`` - relative illumination ``1 - a r^2`` (r over the half diagonal; ``a`` from the real photos' white
  squares, which includes the lighting's fall-off);

Sensor and processing (replaces the three-channel sensor of :mod:`bench.sim.medium` by a colour-filter-array
sensor and a webcam's image processing):

* ``bayer`` - an RGGB mosaic sampled from the linear image; noise per photosite; demosaiced by OpenCV's edge-aware
  ``cvtColor(COLOR_BayerBG2RGB_EA)`` (OpenCV's Bayer names count from the second row and column: ``BG`` is an RGGB
  sensor, tested);
* ``prnu_dsnu`` - fixed-pattern noise: photo-response non-uniformity (gain, rms ``prnu_pct``) and dark-signal
  non-uniformity (offset, rms ``dsnu_e``), drawn once per camera from ``pattern_seed`` (the same in every frame);
  EMVA 1288 datasheets of small CMOS sensors give PRNU ~0.5-1 % and DSNU ~1-5 e-;
* ``tone`` - the camera's ADC (``adc_bits``) and its output encoding: demosaicing on the ADC codes, then the sRGB
  transfer function (IEC 61966-2-1; a webcam's UVC stream is gamma-encoded) to 8 bits. A manual-exposure camera's
  exposure is scaled by ``exposure_scale`` (the real webcam put the board's white 1.12x above its clip level: 70 %
  of the white squares' centres read 254-255); an automatically exposing camera meters its own scene, its target
  a grey level of its encoded output (FLIR's "target grey value" is one), i.e. the linear level ``srgb_eotf(target)``;
* ``sharpen`` - the camera's sharpening: an unsharp mask of the luma (``amount``, Gaussian ``sigma_px``) with a
  coring threshold (``coring_dn``) below which detail is left alone (:func:`unsharp_luma`). The real photos' edges
  are crisper than a perfect pixel-integrating camera's (erf sigma 0.46 px against 0.51 px) and dip 37 DN below the
  black level 1-3 px beside the edge; amount 1.97 and sigma 1.66 px are fitted to their median edge profile, coring
  0.7 DN to their black squares' noise (1.47 DN);
* ``frame_grabber`` - an analog video camera's frame grabber (only a camera whose optics preset gives a
  ``sensor.digitiser_px``): the thesis's underwater camera, the analog MCH-3000P, "converted to digital format using
  a Pinnacle PCTV video card [with] a resolution of 240 x 320 pixels" and "interpolated using a cubic spline function
  in Matlab" to 480 x 640 (section 5.3). Modelled as: the camera's frame averaged over the card's sample cells
  (``cv2.INTER_AREA``: vertically the two rows of a CCD's field integration, horizontally the video low-pass and
  the sampling aperture), 8-bit samples, then interpolated back to the camera's size by ``upsample``:
  ``cubic_spline`` (the interpolating cubic B-spline, ``scipy.ndimage.zoom(order=3)``, pixel centres aligned as
  Matlab's ``imresize``), ``bicubic`` (OpenCV's cubic convolution) or ``bilinear`` (:func:`frame_grab`);
* ``jpeg`` - the camera's JPEG at ``quality`` (``cv2.imencode``; the real photos' quantisation tables are IJG
  quality 90 exactly).

Reproducibility: every random draw comes from child generators of the frame's seed (``rng.spawn``) or of
``pattern_seed``; nothing depends on the number of threads.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import cv2
import numpy as np

from bench.errors import ConfigError

#: the stages of the realistic profile, in the order they are applied (each can be switched off alone)
STAGES = ("print_lines", "print_scale", "toner", "flatness", "cockle", "handling", "fold", "distortion", "chromatic",
          "defocus", "motion", "rolling_shutter", "vignetting", "bayer", "prnu_dsnu", "tone", "sharpen",
          "frame_grabber", "jpeg")
IMAGING_NAMES = ("realistic", "ideal")
#: version of this module's algorithms, part of the render cache key of realistic images (bump when a code change
#: alters them): 2 = bilinear warp (was bicubic); 3 = the lens Gaussian once after the defocus levels; 4 = a sheet
#: that is not flat drawn as meshes through its crossings (was boxes tilted to the bow's slope)
IMAGING_VERSION = 4

#: the real webcam photos' radial calibration (tools/real_camera_stats.py, ``radial_k1``/``radial_k2``: k1 k2, 19
#: views, RMS 0.577 px), in normalised coordinates. No decentering: the photos' p1 -0.0056, p2 -0.0158 (Heikkilä,
#: RMS 0.557 px) are what a hand-held, cockled board puts into those terms, since renders of such a board through a
#: lens without decentering calibrate to p1 -0.026, p2 -0.012 (docs/realistic_imaging.md 3.1); as a true lens they
#: shifted Table 3's principal point 37 px. k3 = 0 (7 x 7 corners cannot separate it).
WEBCAM_DISTORTION = (-0.0262, -0.2066, 0.0, 0.0, 0.0)

#: The realistic profile of a 640 x 480 USB webcam (the thesis's Logitech, the real photos' camera). Units in keys.
REALISTIC = {
    # target: tools/real_camera_stats.py on the real photos (line offsets and cockle fitted with the board's 3-D
    # shape, for a 25 mm square; bow: per-view quadratic fit, median, an upper bound)
    "print_lines": {"feed_rms_mm": 0.09, "scan_rms_mm": 0.05},
    "print_scale": {"scale_rms_pct": 0.2},
    "toner": {"black_reflectance": 0.018},
    "flatness": {"bow_sagitta_mm": 0.6},
    "cockle": {"rms_mm": 0.42, "length_along_rows_mm": 25.0, "length_across_rows_mm": 17.0},
    "handling": {"rms_mm": 0.25, "length_along_rows_mm": 22.0, "length_across_rows_mm": 19.0},
    "fold": {"fold_error_rms_deg": 0.2},
    # optics
    "distortion": {"dist": list(WEBCAM_DISTORTION), "thin_prism": [0.0005, 0.0, -0.0005, 0.0]},
    "chromatic": {"lateral_ca_r": -7.7e-5, "lateral_ca_b": -5.0e-5},
    # 1/6" sensor of 3.6 um pixels, f = 975 px * 3.6 um = 3.5 mm, f/2.4, fixed focus at 1.0 m (webcam datasheet-like)
    "defocus": {"pixel_pitch_um": 3.6, "f_number": 2.4, "focus_distance_m": 1.0, "lens_sigma_px": 0.3},
    "motion": {"angular_rate_rms_deg_per_s": 0.05, "exposure_s": 0.02},
    "rolling_shutter": {"readout_s": 0.03},
    "vignetting": {"falloff_at_corner": 0.19},
    # sensor
    "bayer": {"pattern": "RGGB", "demosaic": "edge_aware"},
    "prnu_dsnu": {"prnu_pct": 0.8, "dsnu_e": 3.0, "pattern_seed": 12},
    "tone": {"adc_bits": 10, "exposure_scale": 1.12},
    "sharpen": {"amount": 1.97, "sigma_px": 1.66, "coring_dn": 0.7},
    # an analog camera's frame grabber (only where the optics preset gives sensor.digitiser_px): section 5.3
    "frame_grabber": {"upsample": "cubic_spline"},
    "jpeg": {"quality": 90},
}

_KEYS = {"print_lines": ("feed_rms_mm", "scan_rms_mm"), "print_scale": ("scale_rms_pct",),
         "toner": ("black_reflectance",),
         "flatness": ("bow_sagitta_mm",), "cockle": ("rms_mm", "length_along_rows_mm", "length_across_rows_mm"),
         "handling": ("rms_mm", "length_along_rows_mm", "length_across_rows_mm"),
         "fold": ("fold_error_rms_deg",), "distortion": ("dist", "thin_prism"),
         "chromatic": ("lateral_ca_r", "lateral_ca_b"),
         "defocus": ("pixel_pitch_um", "f_number", "focus_distance_m", "lens_sigma_px"),
         "motion": ("angular_rate_rms_deg_per_s", "exposure_s"), "rolling_shutter": ("readout_s",),
         "vignetting": ("falloff_at_corner",), "bayer": ("pattern", "demosaic"),
         "prnu_dsnu": ("prnu_pct", "dsnu_e", "pattern_seed"), "tone": ("adc_bits", "exposure_scale"),
         "sharpen": ("amount", "sigma_px", "coring_dn"), "frame_grabber": ("upsample",),
         "jpeg": ("quality",)}
_BOUNDS = {"feed_rms_mm": (0, 5), "scan_rms_mm": (0, 5), "scale_rms_pct": (0, 5), "bow_sagitta_mm": (0, 20),
           "rms_mm": (0, 10), "length_along_rows_mm": (1, 1000), "length_across_rows_mm": (1, 1000),
           "fold_error_rms_deg": (0, 10), "lateral_ca_r": (-0.01, 0.01), "lateral_ca_b": (-0.01, 0.01),
           "pixel_pitch_um": (0.5, 50), "f_number": (0.7, 64), "focus_distance_m": (0.05, 1e3),
           "lens_sigma_px": (0, 5), "angular_rate_rms_deg_per_s": (0, 100), "exposure_s": (0, 1), "readout_s": (0, 1),
           "falloff_at_corner": (0, 0.9), "prnu_pct": (0, 20), "dsnu_e": (0, 1e3), "adc_bits": (8, 16),
           "exposure_scale": (0.01, 100), "black_reflectance": (0, 0.5), "amount": (0, 10), "sigma_px": (0.1, 10),
           "coring_dn": (0, 50)}
UPSAMPLE = ("cubic_spline", "bicubic", "bilinear")
_DEMOSAIC = {"bilinear": cv2.COLOR_BayerBG2RGB, "edge_aware": cv2.COLOR_BayerBG2RGB_EA,
             "vng": cv2.COLOR_BayerBG2RGB_VNG}


@dataclass(frozen=True)
class ImagingProfile:
    """A validated imaging profile: ``stages`` maps each enabled stage of :data:`STAGES` to its parameters."""

    name: str
    stages: dict

    def on(self, stage: str) -> bool:
        return stage in self.stages

    def __getitem__(self, stage):
        return self.stages[stage]

    def key(self) -> str:
        """A text that determines the images (part of the render cache keys)."""
        return repr((IMAGING_VERSION, self.name, sorted((k, sorted(v.items())) for k, v in self.stages.items())))


def imaging_profile(name: str = "realistic", off=(), source: str = "imaging", field: str = "imaging",
                    overrides: dict | None = None) -> ImagingProfile:
    """The profile ``name`` (``realistic`` or ``ideal``) with the stages in ``off`` switched off.

    Raises
    ------
    ConfigError
        One line naming ``source`` and ``field`` for an unknown profile or stage name, or a bad override.
    """
    if name not in IMAGING_NAMES:
        raise ConfigError(source, field, f"expected realistic or ideal, got {name!r}")
    if isinstance(off, str) or not all(isinstance(s, str) for s in off):
        raise ConfigError(source, f"{field}_off", f"expected a list of stage names, got {off!r}")
    bad = [s for s in off if s not in STAGES]
    if bad:
        raise ConfigError(source, f"{field}_off", f"unknown stage {bad[0]!r} (known: {', '.join(STAGES)})")
    stages = copy.deepcopy(REALISTIC)  # the overrides are checked under ideal imaging too (a typo is a typo)
    for stage, vals in (overrides or {}).items():
        if stage not in stages or not isinstance(vals, dict):
            raise ConfigError(source, f"{field}_params.{stage}",
                              f"unknown stage or not a mapping (known: {', '.join(STAGES)})")
        for k, v in vals.items():
            if k not in _KEYS[stage]:
                raise ConfigError(source, f"{field}_params.{stage}.{k}",
                                  f"unknown key (known: {', '.join(_KEYS[stage])})")
            stages[stage][k] = v
    for stage, vals in stages.items():
        for k, v in vals.items():
            if k in _BOUNDS:
                lo, hi = _BOUNDS[k]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                    raise ConfigError(source, f"{field}_params.{stage}.{k}", f"expected a number in [{lo:g}, {hi:g}], "
                                                                      f"got {v!r}")
    for k, n in (("dist", 5), ("thin_prism", 4)):  # k1 k2 p1 p2 k3 (OpenCV's order); s1 s2 s3 s4
        v = stages["distortion"][k]
        if (not isinstance(v, (list, tuple)) or len(v) != n
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in v)):
            raise ConfigError(source, f"{field}_params.distortion.{k}", f"expected {n} finite numbers, got {v!r}")
    if not float(stages["tone"]["adc_bits"]).is_integer():
        raise ConfigError(source, f"{field}_params.tone.adc_bits",
                          f"expected whole bits, got {stages['tone']['adc_bits']!r}")
    q = stages["jpeg"]["quality"]
    if isinstance(q, bool) or not isinstance(q, int) or not 1 <= q <= 100:
        raise ConfigError(source, f"{field}_params.jpeg.quality", f"expected an integer in 1..100, got {q!r}")
    if stages["frame_grabber"]["upsample"] not in UPSAMPLE:
        raise ConfigError(source, f"{field}_params.frame_grabber.upsample",
                          f"expected one of {', '.join(UPSAMPLE)}, got {stages['frame_grabber']['upsample']!r}")
    if stages["bayer"]["demosaic"] not in _DEMOSAIC or stages["bayer"]["pattern"] != "RGGB":
        raise ConfigError(source, f"{field}_params.bayer",
                          f"expected pattern RGGB and demosaic one of {', '.join(_DEMOSAIC)}")
    if name == "ideal":
        return ImagingProfile("ideal", {})
    return ImagingProfile("realistic", {k: v for k, v in stages.items() if k not in off})


def profile_from_config(cfg: dict, section: str) -> ImagingProfile:
    """The profile of a loaded scenario's ``section`` (``camera`` or ``sim``): its ``imaging``, ``imaging_off`` and
    ``imaging_params`` (a stage's parameters replaced, e.g. ``{sharpen: {amount: 1.5}}``)."""
    s = cfg[section]
    return imaging_profile(s.get("imaging", "realistic"), s.get("imaging_off", []), cfg["_file"], f"{section}.imaging",
                           s.get("imaging_params") or None)


# ------------------------------------------------------------------------------------------------ target geometry


def target_geometry(profile: ImagingProfile, squares: int, rng: np.random.Generator, square_m: float | None = None
                    ) -> dict:
    """Random geometry errors of one printed two-board rig (board A, board B), drawn from ``rng``.

    ``square_m``: the pattern's square (m; default the thesis rig's, :data:`bench.sim.scenes.rig.SQUARE_M`), which
    sets the cockle's correlation in squares. Returns a dict for :func:`bench.sim.scenes.rig.calibration_rig`:
    ``line_offsets_m`` ``{"a": (xs, ys), "b": ...}`` (offsets of the ``squares + 1`` column and row lines, m),
    ``scale`` (printout / file), ``bow_sagitta_m`` per board, ``dz_m`` per board (``(squares + 1, squares + 1)``
    out-of-plane offsets at the line crossings, m) and ``fold_error_rad``. Every draw is made whether or not its
    stage is on (the others do not change when one is switched off; the cockle's come last, so the draws of the
    stages before it are those of the profile without it).
    """
    from bench.sim.scenes.rig import BLACK_REFLECTANCE, SQUARE_M

    n = squares + 1
    z = {b: (rng.standard_normal(n), rng.standard_normal(n)) for b in ("a", "b")}
    s, bow, fold = rng.standard_normal(), rng.choice([-1.0, 1.0], 2), rng.standard_normal()
    w = {b: rng.standard_normal(n * n) for b in ("a", "b")}
    out = {"line_offsets_m": {b: (np.zeros(n), np.zeros(n)) for b in ("a", "b")}, "scale": 1.0,
           "bow_sagitta_m": {"a": 0.0, "b": 0.0}, "dz_m": {"a": np.zeros((n, n)), "b": np.zeros((n, n))},
           "fold_error_rad": 0.0, "black_reflectance": BLACK_REFLECTANCE}
    if profile.on("print_lines"):
        p = profile["print_lines"]
        # the rows (y) run along the paper feed, the columns (x) across it
        out["line_offsets_m"] = {b: (z[b][0] * p["scan_rms_mm"] * 1e-3, z[b][1] * p["feed_rms_mm"] * 1e-3)
                                 for b in ("a", "b")}
    if profile.on("toner"):
        out["black_reflectance"] = float(profile["toner"]["black_reflectance"])
    if profile.on("print_scale"):
        out["scale"] = 1.0 + s * profile["print_scale"]["scale_rms_pct"] / 100
    if profile.on("flatness"):
        out["bow_sagitta_m"] = {"a": bow[0] * profile["flatness"]["bow_sagitta_mm"] * 1e-3,
                                "b": bow[1] * profile["flatness"]["bow_sagitta_mm"] * 1e-3}
    if profile.on("cockle"):
        L = cockle_factor(profile["cockle"], n, SQUARE_M if square_m is None else square_m)
        out["dz_m"] = {b: (L @ w[b]).reshape(n, n) for b in ("a", "b")}
    if profile.on("fold"):
        out["fold_error_rad"] = float(np.deg2rad(fold * profile["fold"]["fold_error_rms_deg"]))
    return out


def stated_tolerance(profile: ImagingProfile) -> dict | None:
    """The printed rig's tolerances as a user would state them in ``target.yaml`` (``tolerance``, 1 sigma,
    :mod:`bench.camera.target_tolerance`): the target stages' *specification* (their rms and lengths), never their
    draws - like an encoder datasheet. None when no target stage is on."""
    t = {}
    if profile.on("cockle"):
        c = profile["cockle"]
        t["flatness_rms_mm"] = c["rms_mm"]
        t["flatness_length_mm"] = [c["length_along_rows_mm"], c["length_across_rows_mm"]]
    if profile.on("flatness"):
        t["bow_sagitta_mm"] = profile["flatness"]["bow_sagitta_mm"]
    if profile.on("print_lines"):
        t["print_rms_mm"] = [profile["print_lines"]["scan_rms_mm"], profile["print_lines"]["feed_rms_mm"]]
    if profile.on("print_scale"):
        t["scale_rms_pct"] = profile["print_scale"]["scale_rms_pct"]
    if profile.on("fold"):
        t["fold_rms_deg"] = profile["fold"]["fold_error_rms_deg"]
    return t or None


def handling_dz(profile: ImagingProfile, squares: int, rng: np.random.Generator, square_m: float) -> np.ndarray:
    """A hand-held board's flexing in one photo: out-of-plane offsets ``(squares + 1, squares + 1)`` (m) at the line
    crossings, drawn from ``rng`` (zeros, with the draw still made, when the stage is off)."""
    n = squares + 1
    w = rng.standard_normal(n * n)
    if not profile.on("handling"):
        return np.zeros((n, n))
    return (cockle_factor(profile["handling"], n, square_m) @ w).reshape(n, n)


def cockle_factor(params: dict, n: int, square_m: float) -> np.ndarray:
    """``L`` ``(n^2, n^2)`` with ``L L^T`` the cockle's covariance (m^2) at an ``n x n`` grid of line crossings
    ``square_m`` apart, row-major (row index i along y, across the rows; column j along x, along them)."""
    i, j = np.divmod(np.arange(n * n), n)
    dx = (j[:, None] - j[None]) * square_m / (params["length_along_rows_mm"] * 1e-3)
    dy = (i[:, None] - i[None]) * square_m / (params["length_across_rows_mm"] * 1e-3)
    C = (params["rms_mm"] * 1e-3) ** 2 * np.exp(-0.5 * dx ** 2 - 0.5 * dy ** 2)
    w, V = np.linalg.eigh(C)  # a Gaussian covariance is numerically semi-definite: no Cholesky
    return V * np.sqrt(np.clip(w, 0.0, None))


def lens_distortion(profile: ImagingProfile, dist) -> np.ndarray:
    """The true lens's distortion ``(5,)`` under ``profile``: the given one plus the webcam's measured distortion."""
    d = np.zeros(5)
    d[:len(np.ravel(dist))] = np.ravel(dist)
    if profile.on("distortion"):
        d = d + np.asarray(profile["distortion"]["dist"], float)
    return d


def draw_true_lens(lens, rng: np.random.Generator, profile: ImagingProfile, focal_error_pct: float,
                   principal_error_px: float, distortion_error_pct: float | None = None):
    """The true lens of a simulated campaign: the nominal ``lens`` (a :class:`~bench.camera.model.CameraModel`) with
    its focal lengths, principal point and (``distortion_error_pct``) distortion perturbed by uniform draws from
    ``rng`` (+-%, +-px, +-%), then ``profile``'s measured distortion on top (:func:`lens_distortion`)."""
    K = lens.K.copy()
    K[0, 0] *= 1 + rng.uniform(-1, 1) * focal_error_pct / 100
    K[1, 1] *= 1 + rng.uniform(-1, 1) * focal_error_pct / 100
    K[:2, 2] += rng.uniform(-1, 1, 2) * principal_error_px
    dist = lens.dist
    if distortion_error_pct is not None:
        dist = dist * (1 + rng.uniform(-1, 1, 5) * distortion_error_pct / 100)
    return lens.replace(K=K, dist=lens_distortion(profile, dist), model=None, name=f"{lens.name} (true)")


#: ``target.yaml`` of the lab kinds' calibration target, the thesis's two-plane rig (section 5.2)
RIG_TARGET_YAML = "type: two_plane_rig\nsquares: 7\nsize_mm: 197\nmargin_mm: 20\n"


def rig_target_yaml(profile: ImagingProfile) -> str:
    """The rig's ``target.yaml`` with its print tolerances as its maker states them (:func:`stated_tolerance`: the
    specification, not the draws)."""
    import yaml

    tol = stated_tolerance(profile)
    return RIG_TARGET_YAML + (yaml.safe_dump({"tolerance": tol}) if tol else "")


def rig_errors(profile: ImagingProfile, seed: int, salt: int = 0x7A12, squares: int = 7) -> dict | None:
    """The geometry errors of one printed rig (:func:`target_geometry`) from a generator of its own, seeded by the
    scenario's ``seed`` and ``salt`` (the other draws do not change when a target stage is switched off); None under
    ideal imaging."""
    if not profile.stages:
        return None
    return target_geometry(profile, squares, np.random.default_rng(np.random.SeedSequence([seed, salt])))


# ------------------------------------------------------------------------------------------------ closed forms


def coc_diameter_px(depth_m, focal_length_m: float, f_number: float, focus_distance_m: float,
                    pixel_pitch_m: float) -> np.ndarray:
    """Thin-lens circle of confusion diameter (px) of a point at ``depth_m`` (m) for a lens focused at
    ``focus_distance_m``: ``c = (f / N) |d - d_f| / d * f / (d_f - f)`` on the sensor, over the pixel pitch.
    (Aperture diameter ``f / N``; image distance ``v_f = f d_f / (d_f - f)``; similar triangles.) Infinite depth
    gives the limit ``(f / N) f / (d_f - f)``."""
    d = np.asarray(depth_m, float)
    f = focal_length_m
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(np.isinf(d), 1.0, np.abs(d - focus_distance_m) / d)
    return (f / f_number) * ratio * f / (focus_distance_m - f) / pixel_pitch_m


def row_times_s(height: int, readout_s: float) -> np.ndarray:
    """Exposure time of each row (s) relative to the middle row: ``(r - (H - 1) / 2) readout_s / H``."""
    return (np.arange(height) - (height - 1) / 2) * readout_s / height


def disk_kernel(radius_px: float, sub: int = 8) -> np.ndarray:
    """A pillbox PSF of ``radius_px`` (normalised), each tap the covered fraction of its pixel (``sub^2`` samples)."""
    R = int(np.ceil(radius_px + 0.5))
    t = (np.arange(sub) + 0.5) / sub - 0.5
    g = np.arange(-R, R + 1)
    xx = (g[:, None, None, None] + t[None, None, :, None]) ** 2 + (g[None, :, None, None] + t[None, None, None, :]) ** 2
    k = (xx <= radius_px ** 2).mean(axis=(2, 3)).T
    if k.sum() == 0:
        k[R, R] = 1.0
    return (k / k.sum()).astype(np.float32)


def line_kernel(dx_px: float, dy_px: float, sub: int = 16) -> np.ndarray:
    """Motion blur PSF: a uniform segment from ``-(dx, dy)/2`` to ``+(dx, dy)/2`` px, bilinearly splatted."""
    L = max(abs(dx_px), abs(dy_px))
    R = int(np.ceil(L / 2)) + 1
    k = np.zeros((2 * R + 1, 2 * R + 1), np.float64)
    n = max(2, int(np.ceil(L * sub)))
    for s in (np.arange(n) + 0.5) / n - 0.5:
        x, y = R + s * dx_px, R + s * dy_px
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        k[y0, x0] += (1 - fx) * (1 - fy)
        k[y0, x0 + 1] += fx * (1 - fy)
        k[y0 + 1, x0] += (1 - fx) * fy
        k[y0 + 1, x0 + 1] += fx * fy
    return (k / k.sum()).astype(np.float32)


def srgb_oetf(x) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1): linear ``x`` in [0, 1] -> encoded value in [0, 1]."""
    x = np.clip(np.asarray(x, float), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def srgb_eotf(v) -> np.ndarray:
    """The inverse of :func:`srgb_oetf` (IEC 61966-2-1's decoding): encoded ``v`` in [0, 1] -> linear."""
    v = np.clip(np.asarray(v, float), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def unsharp_luma(rgb, amount: float, sigma_px: float, coring_dn: float = 0.0) -> np.ndarray:
    """A camera's sharpening: the unsharp mask of the luma (Rec. 601 weights) with coring, ``out = rgb + amount
    core(Y - G_sigma * Y)`` added to every channel, ``core(d) = sign(d) max(|d| - coring_dn, 0)`` (the threshold
    that keeps an ISP from sharpening its own noise). Float32 ``(H, W, 3)`` in DN, not clipped."""
    from bench.sim.medium import REC601_LUMA

    img = np.asarray(rgb, np.float32)
    y = img @ REC601_LUMA
    detail = y - cv2.GaussianBlur(y, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
    if coring_dn > 0:
        detail = np.sign(detail) * np.maximum(np.abs(detail) - np.float32(coring_dn), 0)
    return img + np.float32(amount) * detail[..., None]


def mosaic(rgb) -> np.ndarray:
    """RGGB colour-filter-array samples ``(H, W)`` of an RGB image ``(H, W, 3)``: R at even rows and columns."""
    img = np.asarray(rgb)
    out = img[..., 1].copy()
    out[0::2, 0::2] = img[0::2, 0::2, 0]
    out[1::2, 1::2] = img[1::2, 1::2, 2]
    return out


def demosaic(raw_u8, method: str = "edge_aware") -> np.ndarray:
    """RGB uint8 ``(H, W, 3)`` from an RGGB mosaic ``(H, W)`` uint8 with OpenCV (:data:`_DEMOSAIC`)."""
    return cv2.cvtColor(np.ascontiguousarray(raw_u8), _DEMOSAIC[method])


def frame_grab(rgb_u8, capture_px, upsample: str = "cubic_spline") -> np.ndarray:
    """An analog camera's frame ``rgb_u8 (H, W, 3)`` uint8 through a frame grabber sampling ``capture_px = (w, h)``
    and interpolated back to ``(W, H)`` (section 5.3; the ``frame_grabber`` stage). Returns uint8 ``(H, W, 3)``.

    The grabber's samples are the frame's means over their cells (``cv2.INTER_AREA``), rounded to 8 bits. Pixel
    centres are aligned as Matlab's ``imresize`` and OpenCV's ``resize`` align them: output pixel ``i`` lies at
    sample coordinate ``(i + 0.5) w / W - 0.5``. ``cubic_spline`` is the interpolating cubic B-spline through the
    samples (``scipy.ndimage.zoom``, ``order=3``, ``grid_mode=True``, mirrored at the border), ``bicubic`` OpenCV's
    cubic convolution (``INTER_CUBIC``), ``bilinear`` ``INTER_LINEAR``.
    """
    from scipy.ndimage import zoom

    img = np.asarray(rgb_u8)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"frame_grab: expected an RGB uint8 image (H, W, 3), got {img.dtype} {img.shape}")
    H, W = img.shape[:2]
    w, h = (int(v) for v in capture_px)
    if not (1 <= w <= W and 1 <= h <= H):
        raise ValueError(f"frame_grab: capture {w} x {h} px must not exceed the frame's {W} x {H}")
    if upsample not in UPSAMPLE:
        raise ValueError(f"frame_grab: upsample: expected one of {', '.join(UPSAMPLE)}, got {upsample!r}")
    samples = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)  # uint8: the grabber's 8-bit samples
    if upsample != "cubic_spline":
        return cv2.resize(samples, (W, H), interpolation=cv2.INTER_CUBIC if upsample == "bicubic" else cv2.INTER_LINEAR)
    out = np.empty((H, W, 3), np.float32)
    for c in range(3):
        out[..., c] = zoom(samples[..., c].astype(np.float32), (H / h, W / w), order=3, mode="grid-mirror",
                           grid_mode=True)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


# ------------------------------------------------------------------------------------------------ the image chain


class ImagingChain:
    """The realistic optics and sensor stages of one camera (``K`` (3, 3), ``size`` (W, H)), prepared once.

    :meth:`apply` takes the linear radiance image of the lens stage (after the medium's lamp and water, before the
    sensor) with each pixel's object distance and returns the camera's 8-bit RGB output.
    """

    def __init__(self, profile: ImagingProfile, K, size):
        self.profile = profile
        self.K = np.asarray(K, float)
        self.W, self.H = (int(v) for v in size)
        u, v = np.meshgrid(np.arange(self.W, dtype=np.float32), np.arange(self.H, dtype=np.float32))
        self._u, self._v = u, v
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        self._x, self._y = (u - cx) / fx, (v - cy) / fy
        # static displacement of each output pixel (px): thin prism + lateral CA per channel
        self._static = [np.zeros((self.H, self.W, 2), np.float32) for _ in range(3)]
        if profile.on("distortion"):
            s1, s2, s3, s4 = profile["distortion"]["thin_prism"]
            r2 = self._x ** 2 + self._y ** 2
            d = np.stack([(s1 * r2 + s2 * r2 ** 2) * fx, (s3 * r2 + s4 * r2 ** 2) * fy], -1).astype(np.float32)
            for c in range(3):
                self._static[c] += d
        if profile.on("chromatic"):
            for c, key in ((0, "lateral_ca_r"), (2, "lateral_ca_b")):
                m = profile["chromatic"][key]
                self._static[c] += np.stack([(u - cx) * m, (v - cy) * m], -1).astype(np.float32)
        self._vignette = None
        if profile.on("vignetting"):
            r2n = ((u - (self.W - 1) / 2) ** 2 + (v - (self.H - 1) / 2) ** 2) / ((self.W / 2) ** 2 + (self.H / 2) ** 2)
            self._vignette = (1.0 - profile["vignetting"]["falloff_at_corner"] * r2n).astype(np.float32)[..., None]
        self._prnu = self._dsnu = None
        if profile.on("prnu_dsnu"):
            p = profile["prnu_dsnu"]
            g = np.random.default_rng(int(p["pattern_seed"]))
            self._prnu = (1.0 + g.standard_normal((self.H, self.W), dtype=np.float32) * np.float32(p["prnu_pct"] / 100))
            self._dsnu = g.standard_normal((self.H, self.W), dtype=np.float32) * np.float32(p["dsnu_e"])
        self._row_t = row_times_s(self.H, profile["rolling_shutter"]["readout_s"]).astype(np.float32) \
            if profile.on("rolling_shutter") else None
        self._tone_lut = None  # the sRGB transfer function (IEC 61966-2-1) as a look-up table from the ADC codes
        if profile.on("tone"):
            full = 2 ** int(profile["tone"]["adc_bits"]) - 1
            self._tone_lut = (255.0 * srgb_oetf(np.arange(full + 1) / full)).astype(np.float32)

    # --- stages ------------------------------------------------------------------------------------------------------
    def image_velocity(self, rng: np.random.Generator) -> np.ndarray:
        """Image velocity ``(vx, vy)`` px/s of camera shake: angular rates ``omega ~ N(0, rms^2)`` about x and y, the
        image moving by ``(f_x omega_y, -f_y omega_x)``."""
        if not (self.profile.on("motion") or self.profile.on("rolling_shutter")):
            return np.zeros(2)
        rms = np.deg2rad(self.profile["motion"]["angular_rate_rms_deg_per_s"]) if self.profile.on("motion") \
            else np.deg2rad(REALISTIC["motion"]["angular_rate_rms_deg_per_s"])
        w = rng.standard_normal(2) * rms
        return np.array([self.K[0, 0] * w[1], -self.K[1, 1] * w[0]])

    def warp(self, img, velocity) -> np.ndarray:
        """Geometric stages: thin prism, lateral CA and rolling-shutter row displacement, one remap per channel.

        A scene point imaged at ``p`` by the ideal chain appears at ``p + d(p)``; the output pixel ``q`` samples the
        input at ``q - d(q - d(q))`` (two fixed-point steps of the inverse)."""
        rs = None
        if self._row_t is not None and np.any(velocity):
            rs = np.stack([np.broadcast_to(velocity[0] * self._row_t[:, None], (self.H, self.W)),
                           np.broadcast_to(velocity[1] * self._row_t[:, None], (self.H, self.W))], -1)
        if rs is None and not any(s.any() for s in self._static):
            return img
        out = np.empty_like(img)
        for c in range(3):
            d = self._static[c] if rs is None else self._static[c] + rs.astype(np.float32)
            if not d.any():
                out[..., c] = img[..., c]
                continue
            mx, my = self._u - d[..., 0], self._v - d[..., 1]
            for _ in range(1):  # second fixed-point step: d evaluated at the first estimate (d is smooth)
                dx = cv2.remap(d[..., 0], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                dy = cv2.remap(d[..., 1], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                mx, my = self._u - dx, self._v - dy
            # bilinear: OpenCV 5's bicubic remap moves a blob's centroid by ~0.3x the shift's fraction (measured)
            out[..., c] = cv2.remap(np.ascontiguousarray(img[..., c]), mx, my, cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_REFLECT)
        return out

    def blur(self, img, depth_m, velocity) -> np.ndarray:
        """Defocus (pillbox of the circle of confusion at each pixel's depth, interpolated between radius levels),
        the lens's Gaussian and the motion line, convolved together."""
        base = None
        if self.profile.on("motion") and np.any(velocity):
            t = self.profile["motion"]["exposure_s"]
            base = line_kernel(velocity[0] * t, velocity[1] * t)
        sigma = self.profile["defocus"]["lens_sigma_px"] if self.profile.on("defocus") else 0.0
        if not self.profile.on("defocus"):
            return img if base is None else cv2.filter2D(img, -1, base, borderType=cv2.BORDER_REFLECT)
        p = self.profile["defocus"]
        pitch = p["pixel_pitch_um"] * 1e-6
        f = self.K[0, 0] * pitch
        z = np.asarray(depth_m, float)
        z = np.where(np.isfinite(z) & (z > 0), z, np.inf)
        radius = 0.5 * coc_diameter_px(z, f, p["f_number"], p["focus_distance_m"], pitch)
        step = 0.25  # px between radius levels
        pos = (radius / step).astype(np.float32)
        lo, hi = int(np.floor(pos.min())), int(np.ceil(pos.max()))
        out = np.zeros_like(img)
        for lev in range(lo, hi + 1):
            w = np.maximum(np.float32(0), np.float32(1) - np.abs(pos - lev))
            if not w.any():
                continue
            k = disk_kernel(lev * step) if lev > 0 else np.ones((1, 1), np.float32)
            if base is not None:
                k = cv2.filter2D(np.pad(k, base.shape[0] // 2), -1, base, borderType=cv2.BORDER_CONSTANT)
            b = cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REFLECT) if k.size > 1 else img
            out += w[..., None] * b
        if sigma > 0:  # the lens's Gaussian, shift-invariant: once after the depth-dependent pillbox
            out = cv2.GaussianBlur(out, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        return out

    def sensor(self, img, rng: np.random.Generator, spec) -> np.ndarray:
        """Colour-filter-array sensor and the camera's processing: mosaic, electrons (PRNU), shot + read noise and
        DSNU, gain, ADC, demosaicing, tone curve, sharpening, an analog camera's frame grabber, JPEG. ``spec`` is the
        preset's :class:`bench.sim.medium.Sensor` (None: noise-free)."""
        from bench.sim.medium import SHOT_NOISE_NORMAL_ABOVE_E, jpeg

        bayer, tone = self.profile.on("bayer"), self.profile.on("tone")
        full = 2 ** int(self.profile["tone"]["adc_bits"]) - 1 if tone else 255
        raw = mosaic(img) if bayer else img
        if spec is None:
            codes = np.clip(np.rint(raw * float(full)), 0, full)
        else:
            if tone and spec.auto_exposure_target > 0:  # the target is a grey level of the (encoded) output
                scale = spec.exposure_for(img, float(srgb_eotf(spec.auto_exposure_target))) * spec.full_well_e
            else:
                scale = spec.exposure_for(img) * spec.full_well_e
                if tone:  # a manual exposure: the webcam's own exposure of its scene (measured)
                    scale *= self.profile["tone"]["exposure_scale"]
            lam = np.minimum(raw * np.float32(scale), spec.full_well_e).astype(np.float32)
            prnu = self._prnu if bayer or self._prnu is None else self._prnu[..., None]
            dsnu = self._dsnu if bayer or self._dsnu is None else self._dsnu[..., None]
            if prnu is not None:
                lam = lam * prnu
            zn = rng.standard_normal(lam.shape, dtype=np.float32)
            read = np.float32(spec.read_noise_e)
            e = lam + np.sqrt(lam + read * read) * zn
            low = lam < SHOT_NOISE_NORMAL_ABOVE_E
            if low.any():
                e[low] = rng.poisson(lam[low]).astype(np.float32) + read * zn[low]
            if dsnu is not None:
                e = e + dsnu
            gain = spec.gain_dn_per_e * full / 255.0 if tone else spec.gain_dn_per_e  # DN per electron at the ADC
            codes = np.clip(np.rint(e * np.float32(gain)), 0, full)
        codes = codes.astype(np.uint16 if tone else np.uint8)
        rgb = demosaic(codes, self.profile["bayer"]["demosaic"]) if bayer else codes
        if tone:
            rgb = self._tone_lut[rgb]
        if self.profile.on("sharpen"):
            sh = self.profile["sharpen"]
            rgb = unsharp_luma(rgb, sh["amount"], sh["sigma_px"], sh["coring_dn"])
        if rgb.dtype != np.uint8:
            rgb = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
        if self.profile.on("frame_grabber") and spec is not None and spec.digitiser_px is not None:
            rgb = frame_grab(rgb, spec.digitiser_px, self.profile["frame_grabber"]["upsample"])
        q = self.profile["jpeg"]["quality"] if self.profile.on("jpeg") else 0
        if spec is not None and spec.jpeg_quality and not q:
            q = spec.jpeg_quality
        return jpeg(np.ascontiguousarray(rgb), q)

    def apply(self, img, depth_m, rng: np.random.Generator, spec) -> np.ndarray:
        """The realistic stages on linear radiance ``img (H, W, 3)`` with object distances ``depth_m (H, W)`` (m,
        inf = background): warp, blur, vignetting, sensor. Returns RGB uint8."""
        img = np.asarray(img)
        img = img.astype(np.float32) * np.float32(1 / 255) if img.dtype == np.uint8 else img.astype(np.float32)
        g_motion, g_noise = rng.spawn(2)
        vel = self.image_velocity(g_motion)
        img = self.warp(img, vel)
        img = self.blur(img, depth_m, vel)
        if self._vignette is not None:
            img = img * self._vignette
        return self.sensor(img, g_noise, spec)


def apparent_depth_m(port, depth_z_m, water_path_m) -> np.ndarray:
    """Object distance (m) the lens must focus on: the z-depth in air; through a flat port the paraxial virtual
    image's distance ``d0 + t / n_glass + water path / n_water`` (a flat refracting surface images a point at
    ``1 / n`` of its distance)."""
    if port is None:
        return np.asarray(depth_z_m, float)
    return port.d0 + port.t / port.n_glass + np.asarray(water_path_m, float) / port.n_water


def finish_image(chain: ImagingChain | None, img, water_path_m, focus_depth_m, rng, medium_chain, cos_theta):
    """The last stages of a rendered view: the medium (lamp, water) and the sensor - the ideal chain's
    (:func:`bench.sim.medium.apply_medium`) when ``chain`` is None, else the medium without its sensor followed by
    the realistic optics and colour-filter-array sensor (:meth:`ImagingChain.apply`). Returns RGB uint8."""
    from bench.sim.medium import MediumChain, apply_medium

    if chain is None:
        out = apply_medium(img, water_path_m, rng, medium_chain, cos_theta)
        if out.dtype != np.uint8:
            out = np.clip(np.round(out * 255.0), 0, 255).astype(np.uint8)
        return out
    lit = apply_medium(img, water_path_m, rng, MediumChain(medium_chain.medium, medium_chain.light, None,
                                                          medium_chain.max_blur_px), cos_theta)
    return chain.apply(lit, focus_depth_m, rng, medium_chain.sensor)
