"""Chessboard targets: the two-plane calibration rig of thesis section 5.2 (Figure 41) and planar boards.

Section 5.2: "a 2D calibration rig with two perpendicular planes with 7 x 7 squares in chess pattern. The chess
boards had dimensions 197mm x 197mm." The thesis gives no square size; 197 mm / 7 = 28.142857 mm is taken, the
pattern filling the stated board dimension (then each board has 6 x 6 inner corners, 72 in all, which is the
thesis's "72 coordinates were extracted from the rig", section 5.2.1). A white margin (20 mm by default, an
assumption: the figure is not available) surrounds each pattern, because corner detectors need a quiet border.

Rendering decision: **one box geom per square** (black or white) plus white border strips, all with their printed
face exactly in the board plane, over a backing box. A square's edges are then true geometry, rasterised with
MuJoCo's multisampling: no texture resampling, mipmap blur or texel-centre convention stands between the model and
the image, and the corner positions are exact (float) by construction. There are no coplanar overlapping faces
(no z-fighting): squares and strips tile the plane and the backing lies behind it.

Board frame (OpenCV's object convention): origin at the pattern's outer top-left corner, x along the columns, y
along the rows (down the board), z into the board; the printed face is the plane z = 0 and faces -z. Inner corner
(i, j) (row i, column j, from 0) is at ``((j + 1) s, (i + 1) s, 0)``; corners are listed **row-major**
(``index = i * (cols - 1) + j``), like ``cv2.calibrateCamera`` object points. The top-left square is black.

Rig frame: origin at the bottom of the common edge of the two boards, z up along that edge, board A's printed face
in the plane y = 0 (facing +y, extending along +x), board B's in the plane x = 0 (facing +x, extending along +y):
a concave "open book" viewed from the (+x, +y) side. Seen from there, board A is on the left and board B on the
right, both upright, columns running left to right. ``features["corners"]`` lists board A's 36 corners then board
B's 36, each row-major in its board frame (``T_rig_board_a``, ``T_rig_board_b``).
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import homogeneous, rot_z
from bench.sim.scenes.base import SceneObject, add_color_material, add_geom, mesh, pose

BOARD_SQUARES = 7
BOARD_PATTERN_M = 0.197  # section 5.2
SQUARE_M = BOARD_PATTERN_M / BOARD_SQUARES  # assumption: the pattern fills the stated 197 mm
MARGIN_M = 0.02  # assumption: white quiet border around each pattern
SQUARE_DEPTH_M = 0.002  # thickness of the square tiles (their back faces are hidden)


def _check_board_args(rows, cols, square_m, margin_m, thickness_m):
    if int(rows) != rows or int(cols) != cols or rows < 3 or cols < 3:
        raise ValueError(f"board: rows and cols must be integers >= 3 (squares), got {rows} x {cols}")
    for k, v in (("square_m", square_m), ("margin_m", margin_m), ("thickness_m", thickness_m)):
        if not np.isfinite(v) or v <= 0 or v > 1.0:
            raise ValueError(f"board: {k} must be in (0, 1] m, got {v!r}")
    if thickness_m <= SQUARE_DEPTH_M:
        raise ValueError(f"board: thickness_m must exceed the tile depth {SQUARE_DEPTH_M} m, got {thickness_m}")


def board_corners(rows=BOARD_SQUARES, cols=BOARD_SQUARES, square_m=SQUARE_M):
    """Inner corners of a ``rows x cols``-square board in its board frame, row-major, shape ((rows-1)(cols-1), 3)."""
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    return np.stack([(j.ravel() + 1) * square_m, (i.ravel() + 1) * square_m, np.zeros(i.size)], -1)


def _board_geoms(prefix, rows, cols, s, margin, thickness, mat_black, mat_white, mat_back, lines=None,
                 bow_m: float = 0.0, dz_m=None):
    """Geoms (and their meshes) of one board in its board frame (face z = 0 towards -z): ``(geoms, meshes)``, lists
    of :func:`~bench.sim.scenes.base.add_geom` and ``spec.add_mesh`` keyword arguments.

    ``lines = (xs, ys)``: the printed column and row line positions (m, ``cols + 1`` and ``rows + 1``; default the
    even grid ``k s``); square (i, j) spans ``xs[j]..xs[j+1]`` x ``ys[i]..ys[i+1]``, so the squares still tile the
    pattern. A flat sheet (``bow_m == 0`` and no ``dz_m``) is drawn as box geoms. A sheet that is not flat - the
    cylindrical bow :func:`bow_z` of sagitta ``bow_m`` (``> 0`` into the board, away from the viewer) plus the
    out-of-plane offsets ``dz_m`` ``(rows + 1, cols + 1)`` at the line crossings (the cockle of
    :func:`bench.sim.imaging.target_geometry`) - is drawn as one thin closed mesh per square whose printed face has
    its four corners exactly at the crossings' 3-D positions, so the squares meet at every corner with no gap and
    the rendered corner is the true corner; the white border follows the pattern's outer crossings.
    """
    d = SQUARE_DEPTH_M / 2
    xs, ys = (np.arange(cols + 1) * s, np.arange(rows + 1) * s) if lines is None else lines
    W, H = cols * s, rows * s
    flat = bow_m == 0.0 and (dz_m is None or not np.any(dz_m))
    g, meshes = [], []
    if flat:
        for i in range(rows):
            for j in range(cols):
                mat = mat_black if (i + j) % 2 == 0 else mat_white
                hx, hy = (xs[j + 1] - xs[j]) / 2, (ys[i + 1] - ys[i]) / 2
                xc, yc = (xs[j + 1] + xs[j]) / 2, (ys[i + 1] + ys[i]) / 2
                g.append(dict(name=f"{prefix}_sq_{i}_{j}", kind="box", size=[hx, hy, d], pos=[xc, yc, d],
                              material=mat))
        strips = {"top": ((W / 2, -margin / 2), (W / 2 + margin, margin / 2)),
                  "bottom": ((W / 2, H + margin / 2), (W / 2 + margin, margin / 2)),
                  "left": ((-margin / 2, H / 2), (margin / 2, H / 2)),
                  "right": ((W + margin / 2, H / 2), (margin / 2, H / 2))}
        for k, ((cx, cy), (hx, hy)) in strips.items():
            g.append(dict(name=f"{prefix}_border_{k}", kind="box", size=[hx, hy, d], pos=[cx, cy, d],
                          material=mat_white))
        depth = 0.0
    else:
        Z = bow_z(np.asarray(xs, float)[None, :], W, bow_m) + (0.0 if dz_m is None else np.asarray(dz_m, float))
        P = np.stack(np.broadcast_arrays(np.asarray(xs, float)[None, :], np.asarray(ys, float)[:, None], Z), -1)

        def sheet(name, quad, mat):
            meshes.append(sheet_mesh(f"{name}_mesh", quad, SQUARE_DEPTH_M))
            g.append(dict(name=name, kind="mesh", meshname=f"{name}_mesh", material=mat))

        for i in range(rows):
            for j in range(cols):
                sheet(f"{prefix}_sq_{i}_{j}", [P[i, j], P[i, j + 1], P[i + 1, j + 1], P[i + 1, j]],
                      mat_black if (i + j) % 2 == 0 else mat_white)
        # the white border: a strip beyond each outer edge segment and a patch at each outer corner, at the
        # height of the pattern's outer crossings
        out = {"top": (P[0, :], (0.0, -margin)), "bottom": (P[-1, ::-1], (0.0, margin)),
               "left": (P[::-1, 0], (-margin, 0.0)), "right": (P[:, -1], (margin, 0.0))}
        for k, (edge, (ox, oy)) in out.items():
            o = np.array([ox, oy, 0.0])
            for m in range(len(edge) - 1):
                a, b = edge[m], edge[m + 1]
                sheet(f"{prefix}_border_{k}_{m}", [a, a + o, b + o, b], mat_white)
        for k, (p, ox, oy) in {"tl": (P[0, 0], -1, -1), "tr": (P[0, -1], 1, -1), "br": (P[-1, -1], 1, 1),
                                "bl": (P[-1, 0], -1, 1)}.items():
            c = [p, p + [ox * margin, 0, 0], p + [ox * margin, oy * margin, 0], p + [0, oy * margin, 0]]
            sheet(f"{prefix}_border_{k}", c if ox * oy > 0 else c[::-1], mat_white)
        depth = float(np.max(np.abs(Z)))
    back = (thickness - SQUARE_DEPTH_M) / 2 + depth
    g.append(dict(name=f"{prefix}_backing", kind="box", size=[W / 2 + margin, H / 2 + margin, back],
                  pos=[W / 2, H / 2, SQUARE_DEPTH_M + depth + back], material=mat_back))
    return g, meshes


def sheet_mesh(name: str, quad, depth_m: float) -> dict:
    """A closed mesh of a piece of sheet: the printed face is the quadrilateral ``quad`` ((4, 3) m, board frame,
    ordered so that ``(q1 - q0) x (q2 - q0)`` points along +z, into the board; split along its 0-2 diagonal), the
    back face the same moved ``depth_m`` along +z. Every face's normal points out of the piece. Vertices are
    absolute: MuJoCo places the mesh where they say. Returns ``spec.add_mesh`` keyword arguments."""
    q = np.asarray(quad, float)
    b = q + [0.0, 0.0, depth_m]
    verts = np.vstack([q, b])
    faces = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7)]
    for a, c in ((0, 1), (1, 2), (2, 3), (3, 0)):
        faces += [(a, c, c + 4), (a, c + 4, a + 4)]
    return mesh(name, verts, faces)


def bow_z(x, width_m: float, bow_m: float):
    """Out-of-plane offset (m, along the board's z) of a cylindrical bow of sagitta ``bow_m`` across a pattern of
    width ``width_m``: ``bow (1 - (2 x / W - 1)^2)``, zero at the pattern's left and right edges."""
    u = 2 * np.asarray(x, float) / width_m - 1
    return bow_m * (1 - u ** 2)


#: the printed black's reflectance (the white's is 0.92); a realistic target states its own (``black_reflectance``)
BLACK_REFLECTANCE = 0.03


def _builder(name, boards, black=BLACK_REFLECTANCE):
    """``build(spec, parent)`` of a target: its materials and meshes, a body ``name`` holding one body per
    ``(body name or None, pose or None, geoms, meshes)`` of ``boards`` (None: the geoms go in the body itself)."""
    def build(spec, parent):
        add_color_material(spec, f"{name}_black", (black, black, black, 1), specular=0.0, shininess=0.0)
        add_color_material(spec, f"{name}_white", (0.92, 0.92, 0.92, 1), specular=0.0, shininess=0.0)
        add_color_material(spec, f"{name}_back", (0.45, 0.35, 0.25, 1), specular=0.1, shininess=0.1)
        root = parent.add_body(name=name)
        for body_name, T, geoms, meshes in boards:
            for m in meshes:
                spec.add_mesh(**m)
            body = root if body_name is None else root.add_body(name=body_name, **pose(T))
            for g in geoms:
                add_geom(body, **g)
    return build


def planar_board(rows=BOARD_SQUARES, cols=BOARD_SQUARES, square_m=SQUARE_M, margin_m=MARGIN_M, thickness_m=0.01,
                 name: str = "board", errors: dict | None = None) -> SceneObject:
    """A planar chessboard of ``rows x cols`` squares (m), built in its board frame (module docstring).

    ``errors`` (optional): the printed board's geometry errors as for one board of :func:`calibration_rig`
    (:func:`bench.sim.imaging.target_geometry`): ``line_offsets_m`` ``(xs, ys)`` (offsets of the ``cols + 1``
    column and ``rows + 1`` row lines, m), ``scale`` (printout / file), ``bow_sagitta_m`` (float, the cylindrical
    bow of :func:`bow_z`) and ``black_reflectance``; ``features["corners"]`` are then the true printed corners.

    ``features``: ``corners`` ((rows-1)(cols-1), 3) m, row-major; ``pattern_size`` (cols-1, rows-1) as OpenCV's
    ``patternSize`` (corners per row, per column); ``square_m`` (nominal); ``outline`` (4, 3) the pattern's outer
    corners (nominal).
    """
    _check_board_args(rows, cols, square_m, margin_m, thickness_m)
    corners = board_corners(rows, cols, square_m)
    lines, bow, dz = None, 0.0, None
    if errors:
        off = errors.get("line_offsets_m", (np.zeros(cols + 1), np.zeros(rows + 1)))
        scale = float(errors.get("scale", 1.0))
        if np.shape(off[0]) != (cols + 1,) or np.shape(off[1]) != (rows + 1,):
            raise ValueError(f"board: errors.line_offsets_m: expected {cols + 1} and {rows + 1} offsets, got "
                             f"{np.shape(off[0])} and {np.shape(off[1])}")
        xs = (np.arange(cols + 1) * square_m + np.asarray(off[0], float)) * scale
        ys = (np.arange(rows + 1) * square_m + np.asarray(off[1], float)) * scale
        lines, bow = (xs, ys), float(errors.get("bow_sagitta_m", 0.0))
        dz = _check_dz(errors.get("dz_m"), rows, cols)
        corners = _printed_corners(xs, ys, cols * square_m, bow, dz)
    geoms, meshes = _board_geoms(name, rows, cols, square_m, margin_m, thickness_m, f"{name}_black",
                                 f"{name}_white", f"{name}_back", lines, bow, dz)
    W, H = cols * square_m, rows * square_m
    features = {"corners": corners, "pattern_size": (cols - 1, rows - 1),
                "square_m": float(square_m), "outline": np.array([[0, 0, 0], [W, 0, 0], [W, H, 0], [0, H, 0.0]])}
    black = float((errors or {}).get("black_reflectance", BLACK_REFLECTANCE))
    return SceneObject(name=name, build=_builder(name, [(None, None, geoms, meshes)], black), features=features)


def _check_dz(dz, rows, cols):
    if dz is None:
        return None
    dz = np.asarray(dz, float)
    if dz.shape != (rows + 1, cols + 1) or not np.all(np.isfinite(dz)) or np.max(np.abs(dz)) > 0.05:
        raise ValueError(f"board: errors.dz_m: expected finite offsets below 50 mm at the {rows + 1} x {cols + 1} "
                         f"line crossings, got shape {dz.shape}")
    return dz


def _printed_corners(xs, ys, width_m, bow_m, dz):
    """The inner corners ``((rows-1)(cols-1), 3)`` of a printed sheet, row-major: the crossings of the printed
    lines, with the bow and the out-of-plane offsets ``dz`` (or None)."""
    gx, gy = np.meshgrid(xs[1:-1], ys[1:-1])
    z = bow_z(gx, width_m, bow_m) + (0.0 if dz is None else dz[1:-1, 1:-1])
    return np.c_[gx.ravel(), gy.ravel(), np.ravel(z)]


def rig_board_poses(squares=BOARD_SQUARES, square_m=SQUARE_M, margin_m=MARGIN_M):
    """``(T_rig_board_a, T_rig_board_b)``, each (4, 4): the two board frames in the rig frame (module docstring)."""
    top = margin_m + squares * square_m
    # board a: x_b = -x_rig, y_b = -z_rig, z_b = -y_rig; board b: x_b = +y_rig, y_b = -z_rig, z_b = -x_rig
    return (homogeneous([[-1.0, 0, 0], [0, 0, -1], [0, -1, 0]], [margin_m + squares * square_m, 0.0, top]),
            homogeneous([[0.0, 0, -1], [1, 0, 0], [0, -1, 0]], [0.0, margin_m, top]))


def calibration_rig(squares=BOARD_SQUARES, square_m=SQUARE_M, margin_m=MARGIN_M, thickness_m=0.01,
                    name: str = "rig", errors: dict | None = None) -> SceneObject:
    """The two-plane calibration rig of section 5.2: two perpendicular ``squares x squares`` chessboards.

    Parameters
    ----------
    squares : int
        Squares per side of each board (7 in the thesis).
    square_m : float
        Square size (m); default 0.197 / 7.
    margin_m, thickness_m : float
        White border around each pattern, board thickness (m).
    name : str
        Object name (prefix of the MuJoCo names).
    errors : dict, optional
        The printed and assembled rig's geometry errors (:func:`bench.sim.imaging.target_geometry`):
        ``line_offsets_m`` ``{"a": (xs, ys), "b": (xs, ys)}`` (offsets of the ``squares + 1`` column and row lines,
        m), ``scale`` (printout / file), ``bow_sagitta_m`` ``{"a", "b"}``, ``dz_m`` ``{"a", "b"}`` (out-of-plane
        offsets at the ``(squares + 1)^2`` line crossings, m: the cockle), ``fold_error_rad`` (board B turned
        about the fold) and ``black_reflectance`` (the printed black's, default :data:`BLACK_REFLECTANCE`).
        ``features["corners"]`` are then the true printed corners; None: the exact rig.

    Returns
    -------
    SceneObject
        ``features``: ``corners`` (2 (squares-1)^2, 3) rig frame, board A then B, each row-major;
        ``corners_board_a``, ``corners_board_b`` (same, split); ``T_rig_board_a``, ``T_rig_board_b`` (4, 4);
        ``pattern_size`` per board (OpenCV); ``square_m`` (nominal).
    """
    _check_board_args(squares, squares, square_m, margin_m, thickness_m)
    T_a, T_b = rig_board_poses(squares, square_m, margin_m)
    e = errors or {}
    if e.get("fold_error_rad", 0.0):
        T_b = homogeneous(rot_z(e["fold_error_rad"]), np.zeros(3)) @ T_b  # about the fold (the rig's z axis)
    scale = float(e.get("scale", 1.0))
    boards = []
    corners = {}
    n = squares + 1
    for key, T in (("a", T_a), ("b", T_b)):
        off = e.get("line_offsets_m", {}).get(key, (np.zeros(n), np.zeros(n)))
        xs = (np.arange(n) * square_m + np.asarray(off[0], float)) * scale
        ys = (np.arange(n) * square_m + np.asarray(off[1], float)) * scale
        bow = float(e.get("bow_sagitta_m", {}).get(key, 0.0))
        lines = None if not errors else (xs, ys)
        dz = _check_dz(e.get("dz_m", {}).get(key), squares, squares)
        geoms, m = _board_geoms(f"{name}_{key}", squares, squares, square_m, margin_m, thickness_m, f"{name}_black",
                                f"{name}_white", f"{name}_back", lines, bow, dz)
        boards.append((f"{name}_board_{key}", T, geoms, m))
        if errors:
            local = _printed_corners(xs, ys, squares * square_m, bow, dz)
        else:
            local = board_corners(squares, squares, square_m)
        corners[key] = local @ T[:3, :3].T + T[:3, 3]
    ca, cb = corners["a"], corners["b"]
    features = {"corners": np.vstack([ca, cb]), "corners_board_a": ca, "corners_board_b": cb,
                "T_rig_board_a": T_a, "T_rig_board_b": T_b, "pattern_size": (squares - 1, squares - 1),
                "square_m": float(square_m)}
    return SceneObject(name=name, build=_builder(name, boards, float(e.get("black_reflectance", BLACK_REFLECTANCE))),
                       features=features)
