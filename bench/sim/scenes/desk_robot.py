"""A desk robot in a lab as the x-y table's reference object (issue 12): the thesis's MA 2000 (section 5.2.2).

The thesis's webcam experiment photographed "a robotic manipulator (MA 2000 model) ... placed 700 mm in front of the
web camera" (Figure 45). What such an object does to SIFT that a flat, matte panel does not:

* **relief**: the arm's links stand 0.1-0.3 m in front of and behind each other, so keypoints on *occluding
  contours* (a link's silhouette against the one behind it, or against the wall) are not points of either surface
  and slide along the contour as the camera moves;
* **specular highlights**: brushed aluminium links and glossy servo housings under the lab's ceiling lamp reflect it
  where the surface normal bisects lamp and camera; a highlight's edge moves over the surface with the viewpoint;
* **depth spread**: the lab behind it (a wall with notices 0.45 m behind the arm's centre, the bench top under it)
  puts keypoints from 0.7 to 1.15 m range into the same view (at the thesis's 700 mm).

None of these is an image-noise model: they are geometry, materials and light, rendered by MuJoCo like everything
else, so their effect on the keypoints is whatever SIFT makes of them (measured in docs/realistic_imaging.md).

Object frame (as the panel's, so that :func:`~bench.sim.scenes.xy_table.reference_pose` places it the same way):
origin at the arm's centre of view (the point the experimenter aims the reference camera at), x to the right, y
up, z towards the camera. Dimensions are those of a desktop educational arm (a ~0.55 m reach); they are assumed,
the thesis gives none. ``features``: ``corners`` (4, 3) the wall's visible rectangle (for the overview only),
``faces`` the texturable face names (keys of ``texture_overrides``), ``lamp`` (3,) the ceiling lamp's position.
"""

from __future__ import annotations

import cv2
import numpy as np

from bench.errors import ConfigError
from bench.geometry.transforms import homogeneous
from bench.sim.scenes import textures as tx
from bench.sim.scenes.base import (
    SceneObject,
    add_geom,
    add_texture_material,
    box_mesh,
    disc_mesh,
    frame_from_axis,
    pose,
)

#: texture density (px per metre of surface): ~2x what the webcam resolves at 0.7 m (975 px / 0.7 m)
PX_PER_M = 2800.0
#: the lab (m, object frame): the wall's plane, the bench top's height, the ceiling lamp
WALL_Z_M = -0.45
BENCH_Y_M = -0.30
LAMP_M = (0.25, 0.95, 0.45)
#: materials (MuJoCo ``specular``, ``shininess``): brushed aluminium (rough: a broad lobe), glossy black plastic,
#: painted steel, matte
ALUMINIUM = (0.8, 0.1)
PLASTIC = (0.6, 0.3)
PAINT = (0.3, 0.4)
MATTE = (0.03, 0.05)
FACES = ("wall", "bench", "base", "upper_arm", "forearm", "shoulder", "elbow", "wrist", "toolbox")


def brushed_metal(rng: np.random.Generator, shape, color=(128, 130, 134), screws=6, sticker: str | None = None):
    """Brushed aluminium: streaks along the image rows, scratches, countersunk screws, an optional sticker (BGR)."""
    h, w = tx._check_shape(shape)
    streak = rng.normal(0.0, 1.0, (h, w)).astype(np.float32)
    streak = cv2.blur(streak, (max(3, w // 6), 1))  # brushing: correlated along x
    shade = tx.fractal_noise(rng, (h, w), base_cells=2, octaves=4)
    img = np.asarray(color, np.float32) * (0.85 + 0.2 * shade[..., None]) + 18.0 * streak[..., None]
    img = np.clip(img, 0, 255).astype(np.uint8)
    for _ in range(int(rng.integers(4, 12))):  # scratches
        p0 = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        a, n = rng.uniform(0, np.pi), rng.uniform(0.05, 0.3) * max(h, w)
        cv2.line(img, p0, (int(p0[0] + n * np.cos(a)), int(p0[1] + n * np.sin(a))), (120, 122, 125), 1, cv2.LINE_AA)
    r = max(3, min(h, w) // 14)
    for k in range(screws):
        c = (int((k + 0.5) * w / screws), int(r * 2.2) if k % 2 == 0 else h - int(r * 2.2))
        cv2.circle(img, c, r, (95, 95, 98), -1, cv2.LINE_AA)
        cv2.circle(img, c, r, (60, 60, 62), max(1, r // 5), cv2.LINE_AA)
        a = rng.uniform(0, np.pi)
        d = (int(0.7 * r * np.cos(a)), int(0.7 * r * np.sin(a)))
        cv2.line(img, (c[0] - d[0], c[1] - d[1]), (c[0] + d[0], c[1] + d[1]), (40, 40, 40), max(1, r // 4))
    if sticker:
        sh, sw = h // 2, min(w // 3, int(2.8 * h))
        plate = tx.label_plate(rng, sticker.split("\n"), (max(sh, 8), max(sw, 8)), background=(40, 200, 235),
                               weathering=0.1)
        y0, x0 = (h - plate.shape[0]) // 2, int(rng.integers(w // 8, w - plate.shape[1] - w // 8 + 1))
        img[y0:y0 + plate.shape[0], x0:x0 + plate.shape[1]] = plate
    return img


def _housing(rng, shape, text):
    """A servo's glossy black housing with its moulded label."""
    h, w = tx._check_shape(shape)
    img = np.full((h, w, 3), 28, np.uint8)
    img = np.clip(img + rng.normal(0, 3, (h, w, 1)), 0, 255).astype(np.uint8)
    cv2.rectangle(img, (w // 8, h // 5), (w - w // 8, h - h // 5), (210, 210, 210), max(1, h // 30), cv2.LINE_AA)
    tx.stencil_text(img, text, (w // 6, int(0.62 * h)), 0.22 * h, color=tx.WHITE)
    return img


def _wall(rng, shape, px_per_m):
    """The lab wall behind the arm (BGR): painted plaster, a shelf of binders and labelled boxes, a cork board of
    notices, posters, a clock and a cable tray - the clutter a lab photograph has around its subject."""
    h, w = tx._check_shape(shape)
    img = tx.painted_metal(rng, (h, w), color=(200, 206, 210), wear=0.0, rust=0.0, growth=0.0, bolts=False)

    def px(v):
        return max(1, int(round(v * px_per_m)))

    words = ("SAFETY RULES", "LAB ROTA", "MA 2000 MANUAL", "EXPERIMENT 5.2", "NOTICE", "EMERGENCY STOP",
             "CALIBRATION", "ROBOTICS", "DATA SHEETS", "SPARES", "VISION", "CONTROL")

    def random_line(n0=5, n1=13):
        return "".join(rng.choice(list("ABCDEFGHKLMNPRSTUVW 0123456789-"), int(rng.integers(n0, n1))))

    # a shelf across the upper third: binders with spine labels, boxes with labels
    y_shelf = int(0.42 * h)
    x = 0
    while x < w:
        bw = px(rng.uniform(0.03, 0.08))
        bh = px(rng.uniform(0.22, 0.3))
        colour = tuple(int(c) for c in rng.integers(30, 220, 3))
        if x + bw >= w:
            break
        if rng.random() < 0.75:  # a binder: spine label, finger hole
            cv2.rectangle(img, (x, y_shelf - bh), (x + bw, y_shelf), colour, -1)
            lab = tx.label_plate(rng, [random_line(3, 6)], (px(0.05), max(8, bw - 4)), weathering=0.0)
            yl = y_shelf - bh + px(0.04)
            img[yl:yl + lab.shape[0], x + 2:x + 2 + lab.shape[1]] = lab
            cv2.circle(img, (x + bw // 2, y_shelf - px(0.05)), max(2, bw // 6), (25, 25, 25), -1, cv2.LINE_AA)
        else:  # a box with a label
            bw, bh = px(rng.uniform(0.12, 0.22)), px(rng.uniform(0.1, 0.16))
            if x + bw >= w:
                break
            cv2.rectangle(img, (x, y_shelf - bh), (x + bw, y_shelf), (60, 120, 170), -1)
            lab = tx.label_plate(rng, [words[int(rng.integers(0, len(words)))], random_line()],
                                 (bh // 2, int(bw * 0.7)), weathering=0.0)
            y0, x0 = y_shelf - bh + bh // 4, x + bw // 7
            img[y0:y0 + lab.shape[0], x0:x0 + lab.shape[1]] = lab
        cv2.rectangle(img, (x, y_shelf - bh), (x + bw, y_shelf), (20, 20, 20), 1, cv2.LINE_AA)
        x += bw + px(rng.uniform(0.0, 0.01))
    cv2.rectangle(img, (0, y_shelf), (w, y_shelf + px(0.02)), (90, 80, 70), -1)  # the shelf board
    # below the shelf: a cork board of notices and posters with graphics
    board = (px(0.1), y_shelf + px(0.08), w // 2, h - px(0.1))
    cork = tx.fractal_noise(rng, (board[3] - board[1], board[2] - board[0]), base_cells=30, octaves=3) * 60 + 70
    img[board[1]:board[3], board[0]:board[2]] = np.stack([cork * 0.55, cork * 0.8, cork * 1.15], -1).clip(0, 255)
    for k in range(int(rng.integers(28, 40))):
        nw, nh = px(rng.uniform(0.06, 0.15)), px(rng.uniform(0.08, 0.2))
        x0, y0 = int(rng.integers(0, w - nw)), int(rng.integers(y_shelf + px(0.04), h - nh))
        if k % 4 == 3:  # a poster: a plot, a photo-like blob field, a title
            poster = np.full((nh, nw, 3), 240, np.uint8)
            pts = np.cumsum(rng.normal(0, nh / 20, (12, 2)), 0) + (nw / 2, nh / 2)
            cv2.polylines(poster, [pts.astype(np.int32)], False, tuple(int(c) for c in rng.integers(0, 200, 3)), 2,
                          cv2.LINE_AA)
            for _ in range(6):
                cv2.circle(poster, (int(rng.integers(0, nw)), int(rng.integers(0, nh))), int(rng.integers(3, 12)),
                           tuple(int(c) for c in rng.integers(0, 255, 3)), -1, cv2.LINE_AA)
            tx.stencil_text(poster, words[int(rng.integers(0, len(words)))][:10], (4, max(12, nh // 8)),
                            max(6, nh // 12))
        else:
            paper = (tx.WHITE, (180, 235, 250), (235, 215, 190), (200, 240, 200))[k % 4]
            poster = tx.label_plate(rng, [words[int(rng.integers(0, len(words)))]] + [random_line() for _ in range(3)],
                                    (nh, nw), background=paper, weathering=0.0)
        img[y0:y0 + nh, x0:x0 + nw] = poster
    dial = tx.dial_face(rng, px(0.16), label="LAB")
    y, x = px(0.05), int(0.75 * w)
    img[y:y + dial.shape[0], x:x + dial.shape[1]] = dial
    tray_y = int(0.9 * h)  # a cable tray with cables
    cv2.rectangle(img, (0, tray_y), (w, tray_y + px(0.03)), (150, 150, 150), -1)
    for c in range(5):
        yy = tray_y + px(0.005 + 0.005 * c)
        cv2.line(img, (0, yy), (w, yy + int(rng.integers(-8, 8))), ((30, 30, 30), (30, 30, 160), (160, 60, 30))[c % 3],
                 px(0.003), cv2.LINE_AA)
    return img


def _bench(rng, shape, px_per_m):
    """The bench top: grey laminate with a green cutting mat (a 10 mm grid) under the robot (BGR)."""
    h, w = tx._check_shape(shape)
    base = tx.fractal_noise(rng, (h, w), base_cells=6, octaves=5)
    img = np.stack([base * 40 + 150, base * 40 + 155, base * 40 + 160], -1).astype(np.uint8)
    x0, x1, y0, y1 = int(0.3 * w), int(0.7 * w), int(0.25 * h), int(0.85 * h)
    img[y0:y1, x0:x1] = (60, 120, 40)
    step = max(4, int(0.01 * px_per_m))
    for x in range(x0, x1, step):
        cv2.line(img, (x, y0), (x, y1), (140, 190, 120), 1)
    for y in range(y0, y1, step):
        cv2.line(img, (x0, y), (x1, y), (140, 190, 120), 1)
    return img


def _facing(axis) -> np.ndarray:
    """A rotation whose z axis is ``axis`` (unit, 3)."""
    return frame_from_axis(axis)[:3, :3]


def desk_robot(rng: np.random.Generator, name: str = "ref", texture_overrides=None) -> SceneObject:
    """Generate a seeded desk robot in its lab corner (see the module docstring).

    Parameters
    ----------
    rng : numpy.random.Generator
        Every random choice (the arm's posture within a few degrees, textures) is drawn from it.
    name : str
        Object name, prefix of every MuJoCo name.
    texture_overrides : dict[str, path] or None
        Replace a face's texture by any image file (resized to the face's texture size); keys: :data:`FACES`.

    Returns
    -------
    SceneObject
    """
    overrides = dict(texture_overrides or {})
    unknown = sorted(set(overrides) - set(FACES))
    if unknown:
        raise ConfigError("texture_overrides", unknown[0], f"unknown face; known faces: {', '.join(FACES)}")
    materials, meshes, geoms, files = [], [], [], {}

    def textured(face, mesh, img, spec, **kw):
        """A geom ``<name>_<face>`` of ``mesh`` (``spec.add_mesh`` arguments) carrying ``img``."""
        if face in overrides:
            user = tx.load_image_file(overrides[face], f"texture_overrides.{face}")
            img = cv2.resize(user, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_AREA)
        files[f"{name}_{face}.png"] = tx.encode_png(img)
        meshes.append(mesh)
        materials.append((f"{name}_{face}", f"{name}_{face}.png", spec))
        geoms.append(dict(name=f"{name}_{face}", kind="mesh", meshname=mesh["name"], material=f"{name}_{face}",
                          contype=0, conaffinity=0, **kw))

    def box(face, half, pos, img, spec, euler=(0.0, 0.0, 0.0)):
        """A box whose +z face (turned by ``euler``, rad, xyz) carries ``img``."""
        textured(face, box_mesh(f"{name}_{face}_mesh", half), img, spec, pos=pos, euler=euler)

    def can(face, radius, half_len, pos, text, R):
        """A servo housing: a cylinder along ``R``'s z whose +z cap carries its label."""
        px = int(2 * radius * PX_PER_M)
        textured(face, disc_mesh(f"{name}_{face}_mesh", radius, half_len), _housing(rng, (px, px), text), PLASTIC,
                 **pose(homogeneous(R, pos)))

    def link(face, half, pos, axis, towards, img):
        """An aluminium link: a box along ``axis`` (its local y) whose textured face looks ``towards``."""
        y = np.asarray(axis, float) / np.linalg.norm(axis)
        z = np.asarray(towards, float) - np.dot(towards, y) * y
        z /= np.linalg.norm(z)
        textured(face, box_mesh(f"{name}_{face}_mesh", half), img, ALUMINIUM,
                 **pose(homogeneous(np.column_stack([np.cross(y, z), y, z]), pos)))

    def tex(w_m, h_m):
        return int(round(h_m * PX_PER_M)), int(round(w_m * PX_PER_M))

    # the lab: wall behind, bench top under the arm (its +z face turned up: euler -90 deg about x)
    wall_w, wall_h = 1.6, 1.2
    box("wall", (wall_w / 2, wall_h / 2, 0.01), (0.0, BENCH_Y_M + wall_h / 2, WALL_Z_M - 0.01),
        _wall(rng, tex(wall_w, wall_h), PX_PER_M), MATTE)
    bench_d = 0.9
    box("bench", (0.8, bench_d / 2, 0.015), (0.0, BENCH_Y_M - 0.015, WALL_Z_M + bench_d / 2),
        _bench(rng, tex(1.6, bench_d), PX_PER_M), PAINT, euler=(-np.pi / 2, 0.0, 0.0))
    # the arm: base on the mat, waist axis at x = 0, z = -0.12, turned by a waist angle; the posture varies by a few
    # degrees per seed. A link is a box along its local y; its textured face (local +z) looks ``towards``.
    zc = -0.12
    base_img = tx.painted_metal(rng, tex(0.26, 0.06), color=(150, 70, 30), wear=0.1, rust=0.0, growth=0.0)
    tx.stencil_text(base_img, "MA 2000", (int(0.08 * base_img.shape[1]), int(0.7 * base_img.shape[0])),
                    0.45 * base_img.shape[0], color=tx.WHITE)
    box("base", (0.13, 0.03, 0.11), (0.0, BENCH_Y_M + 0.03, zc), base_img, PAINT)
    waist = np.deg2rad(30 + rng.uniform(-8, 8))  # the arm's plane, turned from facing the camera
    radial = np.array([np.sin(waist), 0.0, np.cos(waist)])  # horizontal, in the arm's plane, towards the camera
    up = np.array([0.0, 1.0, 0.0])
    side = np.cross(up, radial)  # the joints' axes
    shoulder = np.array([0.0, BENCH_Y_M + 0.12, zc])
    can("shoulder", 0.045, 0.05, shoulder, "SERVO 1", _facing(side))
    a_up = np.deg2rad(20 + rng.uniform(-6, 6))  # the upper arm leans back from vertical
    up_len, up_dir = 0.26, np.cos(a_up) * up - np.sin(a_up) * radial
    elbow = shoulder + up_len * up_dir
    link("upper_arm", (0.03, up_len / 2, 0.02), shoulder + up_len / 2 * up_dir, up_dir, side,
         brushed_metal(rng, tex(up_len, 0.06), sticker="MA 2000\nLINK 2").transpose(1, 0, 2).copy())
    can("elbow", 0.035, 0.04, elbow + 0.035 * side, "SERVO 2", _facing(side))
    fore_len, pitch = 0.24, np.deg2rad(35 + rng.uniform(-8, 8))  # the forearm reaches forwards and down
    fore_dir = np.cos(pitch) * radial - np.sin(pitch) * up
    wrist = elbow + fore_len * fore_dir
    link("forearm", (0.025, fore_len / 2, 0.018), elbow + fore_len / 2 * fore_dir, fore_dir, side + up,
         brushed_metal(rng, tex(fore_len, 0.05), screws=3).transpose(1, 0, 2).copy())
    can("wrist", 0.028, 0.035, wrist, "S3", _facing(side))
    for s in (-1, 1):  # gripper fingers (not texturable by the user)
        link(f"finger{'lr'[s > 0]}", (0.006, 0.03, 0.01), wrist + 0.018 * s * side - 0.04 * up, -up, side,
             brushed_metal(rng, (64, 16), screws=1))
    # a toolbox beside the robot (labels, latches): more relief at another depth
    toolbox = tx.painted_metal(rng, tex(0.22, 0.12), color=(40, 40, 190), wear=0.2, rust=0.0, growth=0.0)
    tx.stencil_text(toolbox, "TOOLS", (int(0.2 * toolbox.shape[1]), int(0.6 * toolbox.shape[0])),
                    0.3 * toolbox.shape[0], color=tx.WHITE)
    box("toolbox", (0.11, 0.06, 0.08), (0.21, BENCH_Y_M + 0.06, -0.02), toolbox, PAINT)
    lamp = np.array(LAMP_M)
    half_w, top = 0.5 * wall_w, BENCH_Y_M + wall_h
    corners = np.array([[-half_w, top, WALL_Z_M], [half_w, top, WALL_Z_M], [half_w, BENCH_Y_M, WALL_Z_M],
                        [-half_w, BENCH_Y_M, WALL_Z_M]])

    def build(spec, parent):
        for mat, file_name, (specular, shininess) in materials:
            add_texture_material(spec, mat, file_name, specular, shininess)
        for m in meshes:
            spec.add_mesh(**m)
        parent.add_light(name=f"{name}_lamp", pos=lamp, dir=-lamp / np.linalg.norm(lamp), diffuse=[0.15] * 3,
                         specular=[0.7] * 3, castshadow=False)
        for g in geoms:
            add_geom(parent, **g)

    return SceneObject(name, build, files, {"corners": corners, "faces": list(FACES), "lamp": lamp})
