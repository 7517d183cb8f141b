"""A procedural subsea manifold panel (issue 3, item 5): the in-situ scenario's work site.

Panel frame (all features are given in it, metres): origin at the centre of the backplate's front face, x to the
right, y up, z out of the face towards the viewer (the robot). The panel has

* a textured backplate (painted steel with paint wear, rust streaks, marine growth, stencilled ID text, seams,
  hazard band) inside a frame of four painted beams (hazard stripes on the bottom beam, a title plate on the top one);
* valves with protruding handles in several orientations: T-bars, hand wheels and paddles on stems that stand on the
  face or are tilted by up to 30 deg, each with its own ID tag plate;
* ROV torque-tool receptacles (class-4 style buckets on square flanges, dark bore with the square drive and the two
  anti-rotation slots), docking buckets (funnels) and pressure gauges (dial faces with ticks, numbers and needle);
* header pipes along the rows.

Layout: a 4 x 3 grid of slots in the frame's opening, assigned to 6 valves, 2 receptacles, 1 docking bucket and
3 gauges by a seeded permutation, with seeded jitter, handle types, orientations and colours.

``features`` (all in the panel frame):
``corners`` (4, 3) the backplate front-face corners (top-left, top-right, bottom-right, bottom-left);
``frame_corners`` (4, 3) the same for the frame's front face;
``valves`` {``valve_k``: {type, centre (handle centre = hub at the stem tip), axis (unit stem direction, out of the
panel), base (stem foot on the face), handle_dir (unit direction of the bar/lever, perpendicular to axis)}};
``receptacles``, ``docking_buckets``, ``gauges``: {name: {centre (front-face centre), axis}};
``faces`` the texturable face names (keys for ``texture_overrides``); ``size_m`` (width, height).
"""

from __future__ import annotations

from functools import partial

import cv2
import numpy as np

from bench.errors import ConfigError
from bench.sim.scenes import textures as tx
from bench.sim.scenes.base import (
    SceneObject,
    add_color_material,
    add_geom,
    add_texture_material,
    box_mesh,
    disc_mesh,
    frame_from_axis,
    frustum_mesh,
    pose,
)

PX_PER_M_BACKPLATE = 1700.0  # backplate texture density (~3x a 640 px view of the whole panel at 1 m)
#: surface detail of the backplate (see :func:`bench.sim.scenes.textures.surface_detail`; assumed densities for a
#: panel some months after installation): paint chips and hard growth per m^2, bolt spacing along the plate seams
CHIPS_PER_M2 = 400.0
HARD_GROWTH_PER_M2 = 600.0
BOLT_PITCH_MM = 90.0
FRAME_WIDTH_M = 0.06
FRAME_DEPTH_M = 0.07  # the frame's front face is at z = FRAME_DEPTH_M - PLATE_THICKNESS_M
PLATE_THICKNESS_M = 0.02

HANDLE_COLOURS = {"yellow": (0.92, 0.75, 0.08, 1), "orange": (0.93, 0.42, 0.08, 1), "red": (0.75, 0.1, 0.08, 1),
                  "blue": (0.1, 0.3, 0.7, 1)}
VALVE_TYPES = ("t_bar", "wheel", "paddle")


class _Builder:
    """Accumulates materials (``f(spec)``), meshes (``spec.add_mesh`` arguments), files and bodies (``f(parent)``)
    of one object (names prefixed with the object name)."""

    def __init__(self, name, overrides):
        self.name = name
        self.assets, self.meshes, self.bodies, self.files, self.faces = [], [], [], {}, []
        self.overrides = dict(overrides or {})

    def n(self, suffix):
        return f"{self.name}_{suffix}"

    def color(self, suffix, rgba, specular=0.3):
        self.assets.append(partial(add_color_material, name=self.n(suffix), rgba=rgba, specular=specular,
                                   shininess=0.3))
        return self.n(suffix)

    def textured_face(self, face, img):
        """Register texture ``img`` (BGR) for ``face`` (applying an override) and return the material name."""
        self.faces.append(face)
        if face in self.overrides:
            user = tx.load_image_file(self.overrides[face], f"texture_overrides.{face}")
            img = cv2.resize(user, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_AREA)
        fname = f"{self.n(face)}.png"
        self.files[fname] = tx.encode_png(img)
        self.assets.append(partial(add_texture_material, name=self.n(face), file_name=fname))
        return self.n(face)

    def build(self, spec, parent):
        """Add the object: its materials and meshes to ``spec``, its body ``name`` into ``parent``."""
        for add in self.assets:
            add(spec)
        for m in self.meshes:
            spec.add_mesh(**m)
        body = parent.add_body(name=self.name)
        for add in self.bodies:
            add(body)

    def geom(self, name, kind, material, size=(), **kw):
        """Register a geom ``name`` of the object body (``kind`` and fields as :func:`add_geom`)."""
        self.bodies.append(partial(add_geom, name=name, kind=kind, material=material, size=size, **kw))

    def body(self, name, T, geoms):
        """Register a body ``name`` at ``T`` holding ``geoms`` (keyword dicts of :func:`add_geom`)."""
        def build(parent):
            body = parent.add_body(name=name, **pose(T))
            for g in geoms:
                add_geom(body, **g)
        self.bodies.append(build)


def manifold_panel(rng: np.random.Generator, width_m=1.2, height_m=0.8, texture_overrides=None,
                   name: str = "panel") -> SceneObject:
    """Generate a seeded subsea manifold panel.

    Parameters
    ----------
    rng : numpy.random.Generator
        Every random choice (layout jitter, handle types and angles, textures) is drawn from it.
    width_m, height_m : float
        Backplate size (m); at least 0.5 x 0.35 m (the slot grid must hold the components).
    texture_overrides : dict[str, path] or None
        Replace a face's texture by any image file (resized to the face's texture size). Keys: ``features["faces"]``.
    name : str
        Object name, prefix of every MuJoCo name.

    Returns
    -------
    SceneObject
        Built in the panel frame (a body ``name``; see the module docstring), with its features.
    """
    w, h = float(width_m), float(height_m)
    if not (np.isfinite(w) and np.isfinite(h)) or w < 0.5 or h < 0.35 or w > 10 or h > 10:
        raise ValueError(f"panel size: expected 0.5 <= width_m <= 10 and 0.35 <= height_m <= 10, got {w} x {h}")
    overrides = dict(texture_overrides or {})
    b = _Builder(name, overrides)
    fw, fd, pt = FRAME_WIDTH_M, FRAME_DEPTH_M, PLATE_THICKNESS_M
    inner_w, inner_h = w - 2 * fw, h - 2 * fw
    ncol, nrow = 4, 3
    sw, sh = inner_w / ncol, inner_h / nrow
    scale = min(sw / 0.27, sh / 0.227, 1.6)  # component size follows the slot size (1 at the default 1.2 x 0.8)

    kinds = ["valve"] * 6 + ["receptacle"] * 2 + ["docking"] + ["gauge"] * 3
    kinds = [kinds[i] for i in rng.permutation(len(kinds))]
    slots = []
    for r in range(nrow):
        for c in range(ncol):
            cx = -inner_w / 2 + (c + 0.5) * sw + rng.uniform(-0.08, 0.08) * sw
            cy = inner_h / 2 - (r + 0.45) * sh + rng.uniform(-0.06, 0.06) * sh
            slots.append((r, c, cx, cy))

    # --- backplate texture: paint, wear, rust, growth, seams, stencils, slot markings ---
    tw_px = int(round(w * PX_PER_M_BACKPLATE))
    th_px = int(round(h * PX_PER_M_BACKPLATE))

    def to_px(x, y):
        return int(round((x + w / 2) / w * tw_px)), int(round((h / 2 - y) / h * th_px))

    paint = [(130, 110, 60), (60, 90, 110), (110, 115, 112), (40, 120, 200)][int(rng.integers(0, 4))]
    plate = tx.painted_metal(rng, (th_px, tw_px), color=paint, wear=0.45, rust=0.45, growth=0.35, bolts=False)
    seams = []
    for k in range(1, 3):  # welded seams / plate joints
        x = int(tw_px * k / 3 + rng.integers(-20, 20))
        cv2.line(plate, (x, 0), (x, th_px), (40, 40, 40), 3, cv2.LINE_AA)
        seams.append(x)
    # millimetre-to-centimetre detail (paint chips, hard growth, bolted seams) from a child generator, so that the
    # caller's stream (scenario geometry drawn after the panel) does not depend on it
    detail_rng = rng.spawn(1)[0] if getattr(rng.bit_generator, "seed_seq", None) is not None else rng
    tx.surface_detail(detail_rng, plate, PX_PER_M_BACKPLATE / 1e3, chips_per_m2=CHIPS_PER_M2,
                      growth_per_m2=HARD_GROWTH_PER_M2, bolt_pitch_mm=BOLT_PITCH_MM, seams_x_px=seams)
    band_y = to_px(0, -h / 2 + fw + 0.03)[1]
    band = tx.hazard_stripes((int(0.03 * PX_PER_M_BACKPLATE), tw_px), stripe_px=int(0.025 * PX_PER_M_BACKPLATE))
    plate[band_y - band.shape[0]:band_y] = band
    stencils = [f"PLEM-{int(rng.integers(1, 99)):02d}",
                f"M{int(rng.integers(100, 999))}-{'ABCDEFGH'[rng.integers(0, 8)]}",
                "NO STEP", "ROV ACCESS", f"WD {int(rng.integers(300, 2500))} M", "ISOLATE BEFORE INTERVENTION"]
    for text in stencils:
        x, y = rng.uniform(-w / 2 + fw, w / 2 - fw - 0.25), rng.uniform(-h / 2 + fw + 0.05, h / 2 - fw - 0.02)
        tx.stencil_text(plate, text, to_px(x, y), float(rng.uniform(0.018, 0.03)) * PX_PER_M_BACKPLATE,
                        color=tx.WHITE if rng.random() < 0.5 else tx.BLACK)

    features = {"valves": {}, "receptacles": {}, "docking_buckets": {}, "gauges": {}}
    counters = {"valve": 0, "receptacle": 0, "docking": 0, "gauge": 0}
    mat_dark = b.color("dark", (0.04, 0.04, 0.045, 1), specular=0.0)
    mat_steel = b.color("steel", (0.55, 0.56, 0.57, 1), specular=0.5)
    mat_body = b.color("valve_body", (0.25, 0.27, 0.3, 1), specular=0.3)
    handle_mats = {k: b.color(f"handle_{k}", v, specular=0.2) for k, v in HANDLE_COLOURS.items()}
    mat_pipe = b.color("pipe", (0.35, 0.36, 0.33, 1), specular=0.25)
    mat_bucket = b.color("bucket", (0.9, 0.55, 0.1, 1), specular=0.2)
    mat_dock = b.color("dock", (0.92, 0.78, 0.1, 1), specular=0.2)

    # header pipes along the rows (behind the components)
    for r in range(nrow):
        y = inner_h / 2 - (r + 0.45) * sh - 0.06 * sh
        b.geom(b.n(f"pipe_{r}"), "capsule", mat_pipe, [0.018 * scale],
               fromto=[-inner_w / 2, y, 0.02 * scale, inner_w / 2, y, 0.02 * scale])

    for (r, c, cx, cy), kind in zip(slots, kinds, strict=True):
        counters[kind] += 1
        k = counters[kind]
        if kind == "valve":
            vtype = VALVE_TYPES[(k - 1) % 3] if k <= 3 else VALVE_TYPES[int(rng.integers(0, 3))]
            tilt = 0.0 if rng.random() < 0.4 else float(rng.uniform(np.deg2rad(10), np.deg2rad(30)))
            azim = float(rng.uniform(0, 2 * np.pi))
            axis = np.array([np.sin(tilt) * np.cos(azim), np.sin(tilt) * np.sin(azim), np.cos(tilt)])
            roll = float(rng.uniform(0, np.pi))
            colour = list(HANDLE_COLOURS)[int(rng.integers(0, len(HANDLE_COLOURS)))]
            base = np.array([cx, cy + 0.02 * scale, 0.0])
            T = frame_from_axis(axis, base, roll)
            geoms, hub_z = _valve(b, f"valve_{k}", vtype, scale, handle_mats[colour], mat_body, mat_steel)
            b.body(b.n(f"valve_{k}"), T, geoms)
            centre = base + hub_z * axis
            features["valves"][f"valve_{k}"] = {"type": vtype, "centre": centre, "axis": axis, "base": base,
                                                "handle_dir": T[:3, 0].copy(), "colour": colour}
            # ID tag below the valve
            tag = tx.label_plate(rng, [f"V-{100 + 10 * r + c + 1}", str(rng.choice(["OPEN", "CLOSE", "ISOL.",
                                                                                  "VENT", "CHOKE"]))], (128, 320))
            mat = b.textured_face(f"tag_valve_{k}", tag)
            tw_m, th_m = 0.1 * scale, 0.04 * scale
            b.meshes.append(box_mesh(b.n(f"tag_valve_{k}"), (tw_m / 2, th_m / 2, 0.002)))
            ty = cy - 0.42 * sh * 0.9 + th_m / 2
            b.geom(b.n(f"tag_valve_{k}"), "mesh", mat, meshname=b.n(f"tag_valve_{k}"), pos=[cx, ty, 0.002])
        elif kind == "receptacle":
            T = frame_from_axis((0, 0, 1), (cx, cy, 0.0), 0.0)
            flange = tx.painted_metal(rng, (256, 256), color=(40, 100, 210), wear=0.3, rust=0.2, growth=0.15,
                                      bolts=False)
            _bolt_circle(flange, rng)
            tx.stencil_text(flange, f"TT-{k}", (14, 40), 30, tx.BLACK)
            tx.stencil_text(flange, "CL4", (170, 240), 24, tx.BLACK)
            mat = b.textured_face(f"receptacle_{k}_flange", flange)
            geoms, front_z = _receptacle(b, f"receptacle_{k}", scale, mat, mat_bucket, mat_dark, mat_steel)
            b.body(b.n(f"receptacle_{k}"), T, geoms)
            features["receptacles"][f"receptacle_{k}"] = {"centre": np.array([cx, cy, front_z]),
                                                          "axis": np.array([0.0, 0.0, 1.0])}
        elif kind == "docking":
            T = frame_from_axis((0, 0, 1), (cx, cy, 0.0), 0.0)
            geoms, front_z = _docking(b, f"docking_{k}", scale, mat_dock, mat_dark, mat_steel)
            b.body(b.n(f"docking_{k}"), T, geoms)
            features["docking_buckets"][f"docking_{k}"] = {"centre": np.array([cx, cy, front_z]),
                                                           "axis": np.array([0.0, 0.0, 1.0])}
            cv2.putText(plate, "DOCK", to_px(cx - 0.05 * scale, cy - 0.11 * scale), cv2.FONT_HERSHEY_DUPLEX,
                        1.4, tx.WHITE, 3, cv2.LINE_AA)
        else:
            dial = tx.dial_face(rng, 384)
            mat = b.textured_face(f"gauge_{k}", dial)
            T = frame_from_axis((0, 0, 1), (cx, cy, 0.0), 0.0)
            geoms, front_z = _gauge(b, f"gauge_{k}", scale, mat, mat_steel)
            b.body(b.n(f"gauge_{k}"), T, geoms)
            features["gauges"][f"gauge_{k}"] = {"centre": np.array([cx, cy, front_z]),
                                                "axis": np.array([0.0, 0.0, 1.0])}
        # slot outline and number stencilled on the plate
        x0, y0 = to_px(cx - 0.45 * sw, cy + 0.45 * sh)
        x1, y1 = to_px(cx + 0.45 * sw, cy - 0.45 * sh)
        cv2.rectangle(plate, (x0, y0), (x1, y1), tx.WHITE, 3, cv2.LINE_AA)
        tx.stencil_text(plate, f"{r + 1}{'ABCD'[c]}", (x0 + 8, y0 + 40), 30, tx.WHITE)

    mat_plate = b.textured_face("backplate", plate)
    b.meshes.append(box_mesh(b.n("backplate"), (w / 2, h / 2, pt / 2)))
    b.geom(b.n("backplate"), "mesh", mat_plate, meshname=b.n("backplate"), pos=[0, 0, -pt / 2])
    b.bodies.insert(0, b.bodies.pop())

    # --- frame beams (front face at z = fd - pt) ---
    zc = (fd - pt) / 2 - pt / 2  # beams span z in [-pt, fd - pt]
    hz = (fd) / 2
    beams = {"frame_top": ((0.0, h / 2 - fw / 2), (w / 2, fw / 2)),
             "frame_bottom": ((0.0, -h / 2 + fw / 2), (w / 2, fw / 2)),
             "frame_left": ((-w / 2 + fw / 2, 0.0), (fw / 2, h / 2 - fw)),
             "frame_right": ((w / 2 - fw / 2, 0.0), (fw / 2, h / 2 - fw))}
    for face, ((bx, by), (hx, hy)) in beams.items():
        shape = (max(16, int(2 * hy * 1200)), max(16, int(2 * hx * 1200)))
        img = tx.painted_metal(rng, shape, color=tx.SAFETY_YELLOW, wear=0.5, rust=0.5, growth=0.25, bolts=True)
        if face == "frame_bottom":
            img[:, : shape[1] // 3] = tx.hazard_stripes((shape[0], shape[1] // 3), stripe_px=shape[0] // 2)
        mat = b.textured_face(face, img)
        b.meshes.append(box_mesh(b.n(face), (hx, hy, hz)))
        b.geom(b.n(face), "mesh", mat, meshname=b.n(face), pos=[bx, by, zc])
    # title plate on the top beam
    title = tx.label_plate(rng, [f"MANIFOLD {stencils[0]}", f"SN {int(rng.integers(1000, 9999))}-"
                                 f"{'XYZW'[rng.integers(0, 4)]}  {int(rng.integers(1998, 2024))}"], (160, 800))
    mat = b.textured_face("title_plate", title)
    tpw, tph = min(0.4 * w, 0.4), 0.8 * fw
    b.meshes.append(box_mesh(b.n("title_plate"), (tpw / 2, tph / 2, 0.002)))
    b.geom(b.n("title_plate"), "mesh", mat, meshname=b.n("title_plate"),
           pos=[-w / 2 + fw + tpw / 2 + 0.05, h / 2 - fw / 2, fd - pt + 0.002])

    unknown = sorted(set(overrides) - set(b.faces))
    if unknown:
        raise ConfigError("texture_overrides", unknown[0], f"unknown face; known faces: {', '.join(b.faces)}")

    corners = np.array([[-w / 2, h / 2, 0.0], [w / 2, h / 2, 0.0], [w / 2, -h / 2, 0.0], [-w / 2, -h / 2, 0.0]])
    features.update({
        "corners": corners,
        "frame_corners": corners + [0.0, 0.0, fd - pt],
        "faces": list(b.faces),
        "size_m": (w, h),
    })
    return SceneObject(name=name, build=b.build, files=b.files, features=features)


def _bolt_circle(img, rng):
    n = img.shape[0]
    c = (n // 2, n // 2)
    cv2.circle(img, c, int(0.36 * n), (30, 30, 30), 2, cv2.LINE_AA)
    for i in range(8):
        a = 2 * np.pi * i / 8 + 0.2
        p = (int(c[0] + 0.43 * n * np.cos(a)), int(c[1] + 0.43 * n * np.sin(a)))
        cv2.circle(img, p, n // 28, (160, 160, 160), -1, cv2.LINE_AA)
        cv2.circle(img, p, n // 28, (30, 30, 30), 1, cv2.LINE_AA)


def _valve(b, vname, vtype, s, mat_handle, mat_body, mat_steel):
    """Valve in its local frame (z = stem axis, origin at the stem foot); returns (geoms, hub height)."""
    n = lambda suffix: b.n(f"{vname}_{suffix}")  # noqa: E731
    hub = 0.13 * s
    g = [dict(name=n("flange"), kind="cylinder", size=[0.045 * s, 0.01 * s], pos=[0, 0, 0.01 * s], material=mat_body),
         dict(name=n("bonnet"), kind="cylinder", size=[0.026 * s, 0.025 * s], pos=[0, 0, 0.045 * s],
              material=mat_body),
         dict(name=n("stem"), kind="cylinder", fromto=[0, 0, 0.07 * s, 0, 0, hub], size=[0.01 * s],
              material=mat_steel)]
    if vtype == "t_bar":
        L = 0.09 * s
        g.append(dict(name=n("bar"), kind="capsule", fromto=[-L, 0, hub, L, 0, hub], size=[0.012 * s],
                      material=mat_handle))
        g += [dict(name=n(f"knob{i}"), kind="sphere", size=[0.018 * s], pos=[sx * L, 0, hub], material=mat_body)
              for i, sx in enumerate((-1, 1))]
    elif vtype == "wheel":
        R, m = 0.075 * s, 20
        a = 2 * np.pi * np.arange(m + 1) / m
        for i in range(m):
            p0 = [R * np.cos(a[i]), R * np.sin(a[i]), hub]
            p1 = [R * np.cos(a[i + 1]), R * np.sin(a[i + 1]), hub]
            g.append(dict(name=n(f"rim{i}"), kind="capsule", fromto=p0 + p1, size=[0.009 * s], material=mat_handle))
        for i in range(4):
            t = np.pi / 4 + i * np.pi / 2
            g.append(dict(name=n(f"spoke{i}"), kind="capsule", fromto=[0, 0, hub, R * np.cos(t), R * np.sin(t), hub],
                          size=[0.006 * s], material=mat_steel))
        g.append(dict(name=n("hub"), kind="cylinder", size=[0.018 * s, 0.012 * s], pos=[0, 0, hub],
                      material=mat_body))
    else:  # paddle lever
        g.append(dict(name=n("hub"), kind="cylinder", size=[0.022 * s, 0.012 * s], pos=[0, 0, hub],
                      material=mat_body))
        g.append(dict(name=n("paddle"), kind="box", size=[0.08 * s, 0.02 * s, 0.007 * s], pos=[0.07 * s, 0, hub],
                      material=mat_handle))
        g.append(dict(name=n("grip"), kind="box", size=[0.02 * s, 0.021 * s, 0.008 * s], pos=[0.13 * s, 0, hub],
                      material=mat_body))
    return g, hub


def _receptacle(b, rname, s, mat_flange, mat_bucket, mat_dark, mat_steel):
    """Class-4 torque-tool bucket on a square flange; returns (geoms, front-face height)."""
    n = lambda suffix: b.n(f"{rname}_{suffix}")  # noqa: E731
    b.meshes.append(box_mesh(n("flange"), (0.1 * s, 0.1 * s, 0.0075 * s)))
    r_out, half = 0.07 * s, 0.055 * s
    z0 = 0.015 * s
    front = z0 + 2 * half
    g = [dict(name=n("flange"), kind="mesh", meshname=n("flange"), material=mat_flange, pos=[0, 0, 0.0075 * s]),
         dict(name=n("bucket"), kind="cylinder", size=[r_out, half], pos=[0, 0, z0 + half], material=mat_bucket),
         dict(name=n("bore"), kind="cylinder", size=[0.052 * s, 0.0005], pos=[0, 0, front + 0.0005],
              material=mat_dark),
         dict(name=n("drive"), kind="box", size=[0.014 * s, 0.014 * s, 0.001], pos=[0, 0, front + 0.0015],
              material=mat_steel)]
    g += [dict(name=n(f"slot{i}"), kind="box", size=[0.01 * s, 0.006 * s, 0.0008],
               pos=[sx * 0.06 * s, 0, front + 0.0008], material=mat_dark) for i, sx in enumerate((-1, 1))]
    return g, front


def _docking(b, dname, s, mat_dock, mat_dark, mat_steel):
    """Docking funnel (frustum) with a dark opening and a centre pin; returns (geoms, front-face height)."""
    n = lambda suffix: b.n(f"{dname}_{suffix}")  # noqa: E731
    length = 0.11 * s
    b.meshes.append(frustum_mesh(n("funnel"), 0.1 * s, 0.05 * s, length))
    g = [dict(name=n("funnel"), kind="mesh", meshname=n("funnel"), material=mat_dock),
         dict(name=n("opening"), kind="cylinder", size=[0.085 * s, 0.0005], pos=[0, 0, length + 0.0005],
              material=mat_dark),
         dict(name=n("pin"), kind="cylinder", size=[0.015 * s, 0.001], pos=[0, 0, length + 0.002], material=mat_steel)]
    return g, length


def _gauge(b, gname, s, mat_dial, mat_steel):
    """Gauge: steel bezel with the textured dial disc in front; returns (geoms, dial-face height)."""
    n = lambda suffix: b.n(f"{gname}_{suffix}")  # noqa: E731
    b.meshes.append(disc_mesh(n("dial"), 0.058 * s, 0.001))
    front = 0.04 * s + 0.002
    g = [dict(name=n("bezel"), kind="cylinder", size=[0.066 * s, 0.02 * s], pos=[0, 0, 0.02 * s], material=mat_steel),
         dict(name=n("dial"), kind="mesh", meshname=n("dial"), material=mat_dial, pos=[0, 0, front - 0.001])]
    return g, front
