"""Procedural, seeded textures for the subsea scenes (numpy + OpenCV only).

Every generator takes an explicit ``numpy.random.Generator`` and returns an 8-bit **BGR** image ``(H, W, 3)``
(OpenCV's channel order; :func:`encode_png` writes a PNG that MuJoCo reads as RGB). The same generator state gives
byte-identical images: only numpy draws and OpenCV's deterministic drawing/resizing are used.

Texture content is chosen for what the pipeline needs from a subsea panel: structure on several scales that survives
underwater attenuation and blur (stencil text, bolt heads, stripes, paint-wear edges, growth blobs) rather than
pixel-scale noise alone, which the water medium erases.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bench.errors import ConfigError

# Colours (BGR, 0..255)
SAFETY_YELLOW = (20, 190, 235)
PANEL_GREY = (120, 118, 112)
RUST = (30, 70, 140)
DARK_RUST = (20, 40, 80)
BARE_STEEL = (150, 150, 145)
GROWTH_GREEN = (70, 120, 90)
GROWTH_WHITE = (200, 210, 215)
BLACK = (25, 25, 25)
WHITE = (235, 235, 235)

_FONTS = (cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_TRIPLEX)


def _check_shape(shape):
    h, w = (int(v) for v in shape)
    if h < 8 or w < 8:
        raise ValueError(f"texture shape: expected at least 8 x 8 pixels, got {shape}")
    return h, w


def fractal_noise(rng: np.random.Generator, shape, base_cells=4, octaves=5, persistence=0.55):
    """Band-limited fractal value noise in [0, 1].

    Parameters
    ----------
    rng : numpy.random.Generator
    shape : (int, int)
        Image height and width (px).
    base_cells : int
        Number of random lattice cells across the shorter side at the coarsest octave.
    octaves : int
        Octaves, each with twice the lattice density of the previous one.
    persistence : float
        Amplitude ratio between successive octaves.

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    h, w = _check_shape(shape)
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for k in range(int(octaves)):
        cells = base_cells * 2**k
        gh = max(2, int(round(cells * h / min(h, w))) + 1)
        gw = max(2, int(round(cells * w / min(h, w))) + 1)
        grid = rng.random((gh, gw)).astype(np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= persistence
    out /= total
    lo, hi = float(out.min()), float(out.max())
    return (out - lo) / max(hi - lo, 1e-6)


def _blend(img, color, alpha):
    """``img * (1 - alpha) + color * alpha`` with ``alpha (H, W)`` in [0, 1] (float32, in place on ``img``)."""
    img = np.asarray(img, np.float32)
    d = np.subtract(np.asarray(color, np.float32), img, dtype=np.float32)
    d *= np.clip(alpha, 0.0, 1.0).astype(np.float32, copy=False)[..., None]
    img += d
    return img


def painted_metal(rng: np.random.Generator, shape, color=PANEL_GREY, wear=0.35, rust=0.35, growth=0.3, bolts=True):
    """Painted steel with paint wear, rust streaks, marine growth and bolt heads.

    Parameters
    ----------
    rng : numpy.random.Generator
    shape : (int, int)
        Height and width (px).
    color : (3,) BGR
        Paint colour.
    wear, rust, growth : float in [0, 1]
        Amount of bare/worn paint patches, rust streaks (vertical drips), marine-growth blobs and barnacles.
    bolts : bool
        Draw rows of shaded bolt heads along the edges.

    Returns
    -------
    ndarray, shape (H, W, 3), uint8 (BGR)
    """
    h, w = _check_shape(shape)
    s = min(h, w)
    shade = fractal_noise(rng, (h, w), base_cells=3, octaves=6)
    img = np.asarray(color, np.float32) * (0.75 + 0.45 * shade[..., None])
    # Paint wear: thresholded noise exposes primer/steel/rust with a dark rim (sharp, multi-scale edges).
    if wear > 0:
        n = fractal_noise(rng, (h, w), base_cells=5, octaves=5)
        thr = 1.0 - 0.35 * wear
        patch = (n > thr).astype(np.float32)
        rim = cv2.dilate(patch, np.ones((3, 3), np.uint8), iterations=max(1, s // 400)) - patch
        img = _blend(img, BARE_STEEL, patch * 0.8)
        img = _blend(img, RUST, patch * fractal_noise(rng, (h, w), base_cells=12, octaves=3))
        img = _blend(img, DARK_RUST, rim * 0.9)
    # Rust streaks: drips running down from random sources (bolts, seams).
    if rust > 0:
        streak = np.zeros((h, w), np.float32)
        for _ in range(int(6 + 40 * rust)):
            x0 = int(rng.integers(0, w))
            y0 = int(rng.integers(0, max(1, h - h // 8)))
            length = int(rng.uniform(0.05, 0.45) * h)
            width = max(1, int(rng.uniform(0.002, 0.008) * s))
            cv2.line(streak, (x0, y0), (x0 + int(rng.normal(0, 0.01 * s)), min(h - 1, y0 + length)),
                     float(rng.uniform(0.3, 0.9)), width)
        streak = cv2.GaussianBlur(streak, (0, 0), sigmaX=max(0.5, 0.002 * s), sigmaY=max(1.0, 0.01 * s))
        img = _blend(img, RUST, np.clip(streak, 0, 1) * 0.85)
    # Marine growth: soft green/brown blobs, then white barnacles with dark centres.
    if growth > 0:
        blob = np.zeros((h, w), np.float32)
        for _ in range(int(5 + 25 * growth)):
            c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            ax = (int(rng.uniform(0.01, 0.06) * s), int(rng.uniform(0.01, 0.05) * s))
            cv2.ellipse(blob, c, ax, float(rng.uniform(0, 180)), 0, 360, float(rng.uniform(0.4, 1.0)), -1)
        blob = cv2.GaussianBlur(blob, (0, 0), max(1.0, 0.004 * s))
        blob *= 0.6 + 0.4 * fractal_noise(rng, (h, w), base_cells=20, octaves=3)
        img = _blend(img, GROWTH_GREEN, np.clip(blob, 0, 1) * 0.85)
        out = np.clip(img, 0, 255).astype(np.uint8)
        for _ in range(int(40 + 400 * growth)):
            c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            r = max(2, int(rng.uniform(0.002, 0.008) * s))
            cv2.circle(out, c, r, GROWTH_WHITE, -1, cv2.LINE_AA)
            cv2.circle(out, c, max(1, r // 2), (60, 70, 70), -1, cv2.LINE_AA)
        img = out.astype(np.float32)
    out = np.clip(img, 0, 255).astype(np.uint8)
    if bolts:
        _bolt_rows(out, rng)
    grain = (rng.normal(0.0, 4.0, (h, w, 1))).astype(np.float32)
    return np.clip(out.astype(np.float32) + grain, 0, 255).astype(np.uint8)


def surface_detail(rng: np.random.Generator, img, px_per_mm: float, chips_per_m2: float = 400.0,
                   growth_per_m2: float = 600.0, bolt_pitch_mm: float = 0.0, seams_x_px=()):
    """Small, sharp, irregular detail of a structure that has been subsea for a while, drawn in place on ``img``.

    What SIFT finds on a real panel seen from 0.5-1.5 m are blob- and corner-like marks a few millimetres to a few
    centimetres across, each of a different shape. Sizes are physical (``px_per_mm`` of the texture), so the marks
    keep their size whatever the texture resolution:

    * paint chips from tool and ROV contact: irregular polygons of 3-9 mm radius exposing primer, bare steel or
      rust, with a dark rim (``chips_per_m2``);
    * hard marine growth and calcareous deposits (cathodic protection precipitates off-white calcium carbonate;
      barnacles and tube worms settle within months - the densities of hard fouling on North Sea structures are of
      the order of hundreds to thousands per m^2): off-white to grey-green irregular shells of 2-7 mm radius on a
      dark base, half of them in touching clusters of 2-6, 40 % with a dark operculum (barnacles), a quarter with a
      curved tube worm (``growth_per_m2``). Every mark has its own outline: identical marks would give SIFT
      descriptors that match the wrong neighbour a few millimetres away;
    * optionally hex bolt heads along plate seams (columns ``seams_x_px``, every ``bolt_pitch_mm``), each with its
      own rust halo, head orientation and wear.

    The counts are the stated assumptions of the bench, not a survey of a particular site.

    Parameters
    ----------
    rng : numpy.random.Generator
    img : ndarray (H, W, 3) uint8, BGR
        Modified in place and returned.
    px_per_mm : float
        Texture resolution (texture px per mm on the face).
    chips_per_m2, growth_per_m2 : float
        Densities (per m^2 of face).
    bolt_pitch_mm : float
        Bolt spacing along the seams (0: no bolts).
    seams_x_px : sequence of int
        Texture columns of the vertical seams that carry bolts.
    """
    h, w = _check_shape(img.shape[:2])
    if not (np.isfinite(px_per_mm) and px_per_mm > 0):
        raise ValueError(f"px_per_mm: expected a positive number, got {px_per_mm!r}")
    area_m2 = h * w / (px_per_mm * 1e3) ** 2
    mm = float(px_per_mm)
    primer = [(70, 70, 150), (120, 120, 118), BARE_STEEL, RUST, (40, 60, 95)]
    for _ in range(int(round(chips_per_m2 * area_m2))):
        c = np.array([rng.uniform(0, w), rng.uniform(0, h)])
        r = rng.uniform(3.0, 9.0) * mm
        n = int(rng.integers(5, 10))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = r * rng.uniform(0.45, 1.0, n)
        poly = np.round(c + np.stack([rad * np.cos(ang), rad * np.sin(ang)], -1)).astype(np.int32)
        colour = primer[int(rng.integers(0, len(primer)))]
        cv2.fillPoly(img, [poly], tuple(int(v) for v in colour), cv2.LINE_AA)
        cv2.polylines(img, [poly], True, DARK_RUST, max(1, int(round(0.6 * mm))), cv2.LINE_AA)
    shells = [GROWTH_WHITE, (175, 185, 180), (150, 170, 160), (205, 200, 190), (120, 150, 140)]

    def blob(centre, radius, n_min=7, n_max=12, jag=(0.6, 1.0)):
        """An irregular closed outline: every mark its own shape (identical marks would make ambiguous matches)."""
        n = int(rng.integers(n_min, n_max + 1))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = radius * rng.uniform(*jag, n)
        return np.round(np.asarray(centre) + np.stack([rad * np.cos(ang), rad * np.sin(ang)], -1)).astype(np.int32)

    n_growth = int(round(growth_per_m2 * area_m2))
    centres = []
    while len(centres) < n_growth:  # about half of the hard growth settles in clusters of 2-6 (touching shells)
        c = np.array([rng.uniform(0, w), rng.uniform(0, h)])
        k = 1 if rng.random() < 0.5 else int(rng.integers(2, 7))
        for _ in range(min(k, n_growth - len(centres))):
            centres.append(c + rng.normal(0, 6.0 * mm, 2) * (k > 1))
    for c in centres:
        r = rng.uniform(2.0, 7.0) * mm
        outline = blob(c, r)
        rim = (int(rng.uniform(30, 80)),) * 3
        cv2.fillPoly(img, [outline], rim, cv2.LINE_AA)  # dark base plate / shadow
        shell = np.round(c + (outline - c) * rng.uniform(0.7, 0.9)).astype(np.int32)
        shade = shells[int(rng.integers(0, len(shells)))]
        cv2.fillPoly(img, [shell], shade, cv2.LINE_AA)
        u = rng.random()
        if u < 0.4:  # barnacle: a dark, irregular operculum off the shell's centre
            oc = c + rng.uniform(-0.2, 0.2, 2) * r
            cv2.fillPoly(img, [blob(oc, rng.uniform(0.2, 0.4) * r, 4, 6, (0.5, 1.0))],
                         (int(rng.uniform(30, 70)),) * 3, cv2.LINE_AA)
        elif u < 0.65:  # tube worm: a curved calcareous tube leaving the shell
            t = np.linspace(0, 1, 12)
            th = rng.uniform(0, 2 * np.pi) + rng.uniform(-2.0, 2.0) * t
            length = rng.uniform(6.0, 20.0) * mm
            pts = np.cumsum(np.stack([np.cos(th), np.sin(th)], -1) * length / len(t), axis=0) + c
            cv2.polylines(img, [np.round(pts).astype(np.int32)], False, shade,
                          max(1, int(round(rng.uniform(0.8, 1.6) * mm))), cv2.LINE_AA)
    if bolt_pitch_mm > 0:
        pitch = bolt_pitch_mm * mm
        r = max(3, int(round(7.0 * mm)))
        for x in seams_x_px:
            for y in np.arange(0.5 * pitch, h - 0.25 * pitch, pitch):
                cx, cy = int(round(x + rng.uniform(-1, 1) * 0.1 * r)), int(round(y))
                # a rust run below the bolt (its own length), blended into a local window of the texture
                ax = (int(1.3 * r), int(r * rng.uniform(1.5, 3.5)))
                x0, x1 = max(0, cx - ax[0] - 1), min(w, cx + ax[0] + 2)
                y0, y1 = max(0, cy + r - ax[1] - 1), min(h, cy + r + ax[1] + 2)
                if x1 > x0 and y1 > y0:
                    halo = np.zeros((y1 - y0, x1 - x0), np.uint8)
                    cv2.ellipse(halo, (cx - x0, cy + r - y0), ax, 0, 0, 360, 255, -1)
                    win = img[y0:y1, x0:x1]
                    sel = halo > 0
                    win[sel] = (0.5 * win[sel] + 0.5 * np.asarray(RUST)).astype(np.uint8)
                cv2.circle(img, (cx + r // 4, cy + r // 4), r, (30, 30, 30), -1, cv2.LINE_AA)
                grey = int(rng.uniform(120, 175))
                cv2.circle(img, (cx, cy), r, (grey, grey, grey), -1, cv2.LINE_AA)
                a = float(rng.uniform(0, np.pi / 3))
                hexagon = np.array([[cx + 0.75 * r * np.cos(a + k * np.pi / 3),
                                     cy + 0.75 * r * np.sin(a + k * np.pi / 3)] for k in range(6)], np.int32)
                cv2.polylines(img, [hexagon], True, (60, 60, 60), max(1, r // 4), cv2.LINE_AA)
    return img


def _bolt_rows(img, rng):
    """Shaded bolt heads along the four edges (in place)."""
    h, w = img.shape[:2]
    s = min(h, w)
    r = max(3, int(0.012 * s))
    inset = 3 * r
    pitch = max(4 * r, int(0.08 * s))
    pts = [(x, y) for x in range(inset, w - inset + 1, pitch) for y in (inset, h - inset)]
    pts += [(inset, y) for y in range(inset + pitch, h - inset - pitch + 1, pitch)]
    pts += [(w - inset, y) for y in range(inset + pitch, h - inset - pitch + 1, pitch)]
    for x, y in pts:
        cv2.circle(img, (x + r // 4, y + r // 4), r, (30, 30, 30), -1, cv2.LINE_AA)  # shadow
        cv2.circle(img, (x, y), r, (165, 165, 160), -1, cv2.LINE_AA)
        a = float(rng.uniform(0, np.pi / 3))
        hexagon = np.array([[x + 0.7 * r * np.cos(a + k * np.pi / 3), y + 0.7 * r * np.sin(a + k * np.pi / 3)]
                            for k in range(6)], np.int32)
        cv2.polylines(img, [hexagon], True, (70, 70, 70), max(1, r // 5), cv2.LINE_AA)


def hazard_stripes(shape, stripe_px=None, colors=(SAFETY_YELLOW, BLACK), angle_deg=45.0):
    """Diagonal two-colour hazard stripes, ``(H, W, 3)`` uint8 BGR (deterministic)."""
    h, w = _check_shape(shape)
    stripe_px = stripe_px or max(4, min(h, w) // 2)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    a = np.deg2rad(angle_deg)
    band = np.floor((xx * np.cos(a) + yy * np.sin(a)) / stripe_px).astype(int) % 2
    out = np.empty((h, w, 3), np.uint8)
    out[band == 0] = colors[0]
    out[band == 1] = colors[1]
    return out


def stencil_text(img, text, org, height_px, color=BLACK, font=cv2.FONT_HERSHEY_DUPLEX, thickness=None):
    """Draw ``text`` with its baseline-left at ``org`` and cap height ``height_px`` (in place); returns its width."""
    scale = height_px / 22.0  # Hershey fonts are ~22 px high at scale 1
    thickness = thickness or max(1, int(round(height_px / 9)))
    cv2.putText(img, text, (int(org[0]), int(org[1])), font, scale, color, thickness, cv2.LINE_AA)
    (tw, _), _ = cv2.getTextSize(text, font, scale, thickness)
    return tw


def label_plate(rng: np.random.Generator, lines, shape, background=WHITE, ink=BLACK, border=True, weathering=0.3):
    """An engraved/stencilled tag: text lines on a plate with a border, rivets and light weathering."""
    h, w = _check_shape(shape)
    img = np.empty((h, w, 3), np.float32)
    img[:] = background
    img *= (0.85 + 0.15 * fractal_noise(rng, (h, w), base_cells=3, octaves=4))[..., None]
    if weathering > 0:
        spots = fractal_noise(rng, (h, w), base_cells=8, octaves=4)
        img = _blend(img, RUST, np.clip((spots - (1 - 0.3 * weathering)) * 4, 0, 1))
    out = np.clip(img, 0, 255).astype(np.uint8)
    if border:
        t = max(2, h // 25)
        cv2.rectangle(out, (t, t), (w - 1 - t, h - 1 - t), ink, t, cv2.LINE_AA)
        r = max(2, h // 20)
        for cx, cy in ((3 * r + t, 3 * r + t), (w - 3 * r - t, 3 * r + t), (3 * r + t, h - 3 * r - t),
                       (w - 3 * r - t, h - 3 * r - t)):
            cv2.circle(out, (cx, cy), r, (90, 90, 90), -1, cv2.LINE_AA)
    lines = list(lines)
    n = max(1, len(lines))
    line_h = 0.62 * h / n
    for i, text in enumerate(lines):
        cap = line_h * (0.75 if i == 0 else 0.55)
        font = _FONTS[int(rng.integers(0, len(_FONTS)))]
        thickness = max(1, int(round(cap / 8)))
        (tw, _), _ = cv2.getTextSize(text, font, cap / 22.0, thickness)
        if tw > 0.86 * w:  # shrink to fit
            cap *= 0.86 * w / tw
            (tw, _), _ = cv2.getTextSize(text, font, cap / 22.0, thickness)
        y = 0.19 * h + (i + 0.8) * (0.68 * h / n)
        cv2.putText(out, text, (int((w - tw) / 2), int(y)), font, cap / 22.0, ink, thickness, cv2.LINE_AA)
    return out


def dial_face(rng: np.random.Generator, size_px, vmin=0, vmax=None, label=None):
    """A pressure-gauge dial: ticks, numbers, a red zone, a needle at a random reading, and a unit label.

    The dial fills the inscribed circle of a square ``(size_px, size_px, 3)`` BGR image; the corners are bezel grey.
    """
    n = int(size_px)
    _check_shape((n, n))
    vmax = vmax if vmax is not None else int(rng.choice([10, 16, 25, 40, 60, 100, 250, 400]))
    label = label or str(rng.choice(["BAR", "PSI x100", "MPa", "kPa x10"]))
    img = np.empty((n, n, 3), np.uint8)
    img[:] = (110, 110, 110)
    c = (n // 2, n // 2)
    R = int(0.49 * n)
    cv2.circle(img, c, R, (238, 240, 240), -1, cv2.LINE_AA)
    a0, a1 = np.deg2rad(225.0), np.deg2rad(-45.0)  # sweep 270 deg clockwise (image y down)

    def ang(v):
        return a0 + (a1 - a0) * (v - vmin) / (vmax - vmin)

    # red zone over the last 15 %
    cv2.ellipse(img, c, (int(0.8 * R), int(0.8 * R)), 0, -np.rad2deg(ang(vmin + 0.85 * (vmax - vmin))),
                -np.rad2deg(a1), (40, 40, 210), max(2, n // 30), cv2.LINE_AA)
    n_major = 5
    for k in range(n_major * 5 + 1):
        v = vmin + (vmax - vmin) * k / (n_major * 5)
        a = ang(v)
        major = k % 5 == 0
        r0 = R * (0.72 if major else 0.8)
        p0 = (int(c[0] + r0 * np.cos(a)), int(c[1] - r0 * np.sin(a)))
        p1 = (int(c[0] + 0.9 * R * np.cos(a)), int(c[1] - 0.9 * R * np.sin(a)))
        cv2.line(img, p0, p1, BLACK, max(1, n // (60 if major else 150)), cv2.LINE_AA)
        if major:
            txt = f"{v:g}"
            scale = n / 420.0
            (tw, th), _ = cv2.getTextSize(txt, cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, n // 150))
            q = (int(c[0] + 0.55 * R * np.cos(a) - tw / 2), int(c[1] - 0.55 * R * np.sin(a) + th / 2))
            cv2.putText(img, txt, q, cv2.FONT_HERSHEY_SIMPLEX, scale, BLACK, max(1, n // 150), cv2.LINE_AA)
    (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_DUPLEX, n / 500.0, max(1, n // 170))
    cv2.putText(img, label, (c[0] - tw // 2, int(c[1] + 0.45 * R)), cv2.FONT_HERSHEY_DUPLEX, n / 500.0, BLACK,
                max(1, n // 170), cv2.LINE_AA)
    reading = float(rng.uniform(0.1, 0.8))
    a = a0 + (a1 - a0) * reading
    tip = (int(c[0] + 0.85 * R * np.cos(a)), int(c[1] - 0.85 * R * np.sin(a)))
    tail = (int(c[0] - 0.15 * R * np.cos(a)), int(c[1] + 0.15 * R * np.sin(a)))
    cv2.line(img, tail, tip, (30, 30, 160), max(2, n // 45), cv2.LINE_AA)
    cv2.circle(img, c, max(3, n // 22), BLACK, -1, cv2.LINE_AA)
    return img


def encode_png(img) -> bytes:
    """Lossless PNG bytes of a uint8 BGR/gray image (deterministic)."""
    img = np.asarray(img)
    if img.dtype != np.uint8 or img.ndim not in (2, 3):
        raise ValueError(f"image: expected uint8 (H, W[, 3]), got {img.dtype} {img.shape}")
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("image: PNG encoding failed")
    return buf.tobytes()


def load_image_file(path, field: str) -> np.ndarray:
    """Read any image file OpenCV can decode as 8-bit BGR; a missing or unreadable file is a one-line ConfigError."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(str(p), field, "texture file not found")
    img = cv2.imdecode(np.frombuffer(p.read_bytes(), np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise ConfigError(str(p), field, "not a readable image file")
    return img
