"""Chessboard corner extraction for camera calibration (thesis §3.3.3-3.3.5, §5.2.1; OpenCV beside it).

Two extractors return the same :class:`CornerResult`, corners in the same canonical order:

* :func:`extract_corners_thesis` - the thesis's method. Gaussian smoothing, Sobel gradients (Eq. 88-89), edge
  magnitude and direction (Eq. 90-91), non-maximum suppression along four quantised directions with a threshold
  (§3.3.4, Figure 23), then k-means line fitting (§3.3.5, Eq. 92-93) and the corner as the intersection of the two
  fitted lines. As in the thesis (§3.3.5: "in this case there are only two lines to be estimated"; Figure 43) the
  k-means runs per corner on the edge pixels of a window around the predicted corner, with the two board lines
  through that corner as the initial line parameters. Locally the lines are straight even under lens distortion,
  which the thesis's pin-hole model does not describe. The predicted corners come from a rough projection:

  - ``initial_P``: a 3x4 projection matrix of the board geometry (e.g. from an earlier calibration);
  - ``outer_corners_uv``: the manual fallback of §3.3.3 - the outer corners clicked by hand, in the order of
    ``board_geometry.outer_points`` (the six outer corners of the two-plane rig -> DLT, Eq. 55-58; the four extreme
    inner corners of a planar board -> homography);
  - neither (the default): automatic. Each plane of the geometry is a separate planar board: OpenCV's
    ``findChessboardCornersSB`` (fallback ``findChessboardCorners``) finds it, the region is masked and the next plane
    is searched; the labelling of each detection is then fixed by the geometry (see *Ordering*) and each plane's
    initial homography is computed from its four extreme detected corners only (the thesis's "outer corners"), so
    the final corners are the thesis method's own measurement, not OpenCV's.

  Additions to the printed method (each documented where it is done): sub-pixel edge positions by a parabola through
  the edge magnitudes along the quantised direction, a disk around the corner where the X-junction spoils the
  gradient is left out, edge pixels farther than a gate from both lines or whose gradient is not roughly normal to
  the line are not assigned, and the window is re-centred once on the first estimate.
* :func:`extract_corners_opencv` - ``cv2.findChessboardCornersSB`` with ``CALIB_CB_ACCURACY``, falling back to
  ``cv2.findChessboardCorners`` + ``cv2.cornerSubPix``; per plane, like the automatic initialisation above.

Ordering
--------
A square grid of inner corners (e.g. 7x7) looks the same after a 90-degree turn, and detectors return it in any of
its symmetric labellings. The canonical labelling used by both extractors: among the labellings consistent with the
board geometry - proper (not mirrored: the plane's z axis points away from the camera, so x runs right and y down
when the board is seen upright) and, for a multi-plane rig, fitting one projection matrix (DLT residual) with all
corners in front of the camera - the one whose first corner (id 0) is closest to the image's top-left pixel. For a
planar board this means: corner 0 is the extreme corner nearest the top-left, the first row runs from it in the
direction that makes the labelling proper (left-to-right for an upright board). For planar-board calibration any
consistent labelling of a view would do (each view has its own extrinsics, which absorb a relabelling); for the
two-plane rig (one projection matrix for both planes) and for comparing corners between views or extractors the
labelling must be the canonical one.

Pixel convention: OpenCV's, pixel (0, 0) is the centre of the top-left pixel, u right, v down.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import cv2
import numpy as np

from bench.camera import dlt
from bench.geometry.transforms import homogeneous

#: Sobel masks (Eq. 88 and 89), applied as correlations: G_x > 0 where the intensity grows with u
SOBEL_X = np.array([[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0], [-1.0, 0.0, 1.0]])
SOBEL_Y = SOBEL_X.T.copy()
#: the four quantised gradient directions of Figure 23 as pixel steps (du, dv): 0, 45, 90, 135 degrees
DIRECTIONS = np.array([[1, 0], [1, 1], [0, 1], [-1, 1]])
#: OpenCV's RNG state before each chessboard detection (0 = OpenCV's default state, 0xffffffff)
CV_RNG_SEED = 0


# ----------------------------------------------------------------------------------------------------------------------
# board geometry
# ----------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BoardPlane:
    """One chessboard plane: ``inner = (nx, ny)`` inner corners, square side ``square`` (m), pose in the board frame.

    Its corners in the plane frame are ``(i * square, j * square, 0)``, ``i = 0..nx-1`` fastest, ``j = 0..ny-1``; the
    plane frame's z axis points into the board (away from a camera that sees its printed side).
    """

    name: str
    inner: tuple
    square: float
    T_board_plane: np.ndarray

    def points_plane(self) -> np.ndarray:
        """Corners in the plane frame, ``(nx * ny, 3)`` (m), row-major (i fastest)."""
        nx, ny = self.inner
        j, i = np.mgrid[0:ny, 0:nx]
        return np.column_stack([i.ravel() * self.square, j.ravel() * self.square, np.zeros(nx * ny)])

    def points_board(self) -> np.ndarray:
        """Corners in the board (rig) frame, ``(nx * ny, 3)`` (m)."""
        p = self.points_plane()
        return p @ self.T_board_plane[:3, :3].T + self.T_board_plane[:3, 3]


@dataclass(frozen=True)
class BoardGeometry:
    """A calibration target made of chessboard planes; ``outer_points (M, 3)`` are the points to click by hand."""

    name: str
    planes: tuple
    outer_points: np.ndarray

    def object_points(self) -> np.ndarray:
        """All inner corners ``(N, 3)`` in the board frame (m), plane after plane; index = corner id."""
        return np.vstack([p.points_board() for p in self.planes])

    def plane_slices(self) -> list:
        """Index range of each plane's corners in :meth:`object_points`."""
        out, start = [], 0
        for p in self.planes:
            n = p.inner[0] * p.inner[1]
            out.append(slice(start, start + n))
            start += n
        return out

    @property
    def n_corners(self) -> int:
        return sum(p.inner[0] * p.inner[1] for p in self.planes)


def planar_board(inner=(7, 7), square: float = 1.0) -> BoardGeometry:
    """A planar chessboard with ``inner = (nx, ny)`` inner corners (nx per row) of pitch ``square`` (m).

    ``outer_points`` are the four extreme inner corners: corner 0, the end of the first row, the last corner, the start
    of the last row.
    """
    nx, ny = _check_inner(inner)
    if not (np.isfinite(square) and square > 0):
        raise ValueError(f"square: expected a positive length, got {square}")
    plane = BoardPlane("board", (nx, ny), float(square), np.eye(4))
    s = float(square)
    outer = np.array([[0, 0, 0], [(nx - 1) * s, 0, 0], [(nx - 1) * s, (ny - 1) * s, 0], [0, (ny - 1) * s, 0.0]])
    return BoardGeometry("planar", (plane,), outer)


def two_plane_rig(squares: int = 7, size: float = 0.197, margin: float = 0.0) -> BoardGeometry:
    """The thesis's rig (§5.2.1, Figure 41): two perpendicular ``squares x squares`` chessboards of side ``size`` (m).

    Rig frame: origin at the bottom of the common edge (the fold), z up along the fold, plane ``left`` is the x-z plane
    (y = 0, x >= 0), plane ``right`` the y-z plane (x = 0, y >= 0); the camera looks at the printed sides from
    x > 0, y > 0, where ``left`` appears on the left. Each pattern starts ``margin`` (m) from the fold and from the
    bottom (0 in the thesis's figure as far as it can be read; the simulated rig of ``bench.sim.scenes.rig`` uses
    0.02 m and this same frame). The inner corners are the ``(squares-1)^2`` corners of each pattern off its edges
    (36 + 36 = 72 for 7x7 squares), rows from the top, each row left to right as seen from the front, ``left``
    first. ``outer_points``, the points to click by hand (§3.3.3): for ``margin = 0`` the thesis's six outer corners
    of the pattern, clockwise from the top-left (far top of ``left``, top of the fold, far top of ``right``, far
    bottom of ``right``, bottom of the fold, far bottom of ``left``); otherwise the four outer corners of each
    pattern, ``left`` then ``right``, each clockwise from its top-left.
    """
    if int(squares) != squares or squares < 3:
        raise ValueError(f"squares: expected an integer >= 3, got {squares}")
    if not (np.isfinite(size) and size > 0):
        raise ValueError(f"size: expected a positive length (m), got {size}")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin: expected a length >= 0 (m), got {margin}")
    n = int(squares)
    s = size / n
    m = float(margin)
    top = m + (n - 1) * s
    # left plane: x axis -x (left to right = towards the fold), y axis -z (down), z = -y (into the board)
    T_left = homogeneous(np.column_stack([[-1.0, 0, 0], [0, 0, -1.0], [0, -1.0, 0]]), [top, 0.0, top])
    # right plane: x axis +y (away from the fold), y axis -z, z = -x (into the board)
    T_right = homogeneous(np.column_stack([[0, 1.0, 0], [0, 0, -1.0], [-1.0, 0, 0]]), [0.0, m + s, top])
    planes = (BoardPlane("left", (n - 1, n - 1), s, T_left), BoardPlane("right", (n - 1, n - 1), s, T_right))
    lo, hi = m, m + size
    if m == 0.0:
        outer = np.array([[hi, 0, hi], [0, 0, hi], [0, hi, hi], [0, hi, lo], [0, 0, lo], [hi, 0, lo]])
    else:
        outer = np.array([[hi, 0, hi], [lo, 0, hi], [lo, 0, lo], [hi, 0, lo],
                          [0, lo, hi], [0, hi, hi], [0, hi, lo], [0, lo, lo]])
    return BoardGeometry("two_plane_rig", planes, outer.astype(float))


def _check_inner(inner):
    try:
        nx, ny = (int(v) for v in inner)
    except (TypeError, ValueError):
        raise ValueError(f"pattern_size: expected two integers (nx, ny), got {inner!r}") from None
    if (nx, ny) != tuple(inner) or nx < 2 or ny < 2:
        raise ValueError(f"pattern_size: expected two integers >= 2 (inner corners), got {inner!r}")
    return nx, ny


def _as_geometry(board) -> BoardGeometry:
    if isinstance(board, BoardGeometry):
        return board
    return planar_board(_check_inner(board))


# ----------------------------------------------------------------------------------------------------------------------
# result and validation
# ----------------------------------------------------------------------------------------------------------------------
@dataclass
class CornerResult:
    """Result of a corner extraction.

    Attributes
    ----------
    success : bool
        All corners of the geometry were found.
    message : str
        What was done, or why it failed.
    uv : ndarray (N, 2)
        Corner pixels in canonical order (px); empty on failure.
    object_points : ndarray (N, 3)
        The matching corners in the board frame (m).
    ids : ndarray (N,)
        Corner ids (index into ``BoardGeometry.object_points()``).
    lines : ndarray (N, 2, 3)
        Thesis method: the two fitted lines ``a u + b v + c = 0`` (``a^2 + b^2 = 1``) through each corner; NaN for
        OpenCV.
    iterations : int
        Thesis method: largest number of k-means iterations over the corners; 0 for OpenCV.
    method : str
        Which extractor / detector produced the corners.
    initialisation : str
        Thesis method: where the initial projection came from ("initial_P", "manual", "automatic: ...").
    line_rms_px : ndarray (N,)
        Thesis method: RMS distance of the assigned edge points to their fitted line, per corner (px).
    """

    success: bool
    message: str
    uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    object_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    iterations: int = 0
    method: str = ""
    initialisation: str = ""
    line_rms_px: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _failure(message, method, initialisation="", iterations=0) -> CornerResult:
    return CornerResult(False, message, method=method, initialisation=initialisation, iterations=iterations)


def check_image(image, name="image") -> np.ndarray:
    """Validate an image (H, W) or (H, W, 3|4) (BGR as OpenCV reads it) and return it as float64 grey (H, W).

    Raises a one-line ``ValueError`` for an empty array, a wrong shape, NaN or inf.
    """
    if image is None:
        raise ValueError(f"{name}: no image (None); was the file readable?")
    a = np.asarray(image)
    if a.size == 0:
        raise ValueError(f"{name}: empty image, shape {a.shape}")
    if a.ndim == 3 and a.shape[2] in (3, 4):
        if a.dtype == np.uint8:
            a = cv2.cvtColor(a[:, :, :3], cv2.COLOR_BGR2GRAY)
        else:
            a = a[:, :, :3].astype(float) @ np.array([0.114, 0.587, 0.299])
    elif a.ndim != 2:
        raise ValueError(f"{name}: expected shape (H, W) or (H, W, 3), got {a.shape}")
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name}: expected a numeric array, got dtype {a.dtype}")
    a = a.astype(float)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or inf")
    if min(a.shape) < 8:
        raise ValueError(f"{name}: too small ({a.shape[1]}x{a.shape[0]} px)")
    return a


def _to_uint8(gray) -> np.ndarray:
    """Grey float image -> uint8 for OpenCV's detectors (values above 255 are rescaled, not clipped)."""
    hi = gray.max()
    if hi > 255.0 or gray.min() < 0.0:
        lo = gray.min()
        gray = (gray - lo) * (255.0 / max(hi - lo, 1e-12))
    return np.clip(np.rint(gray), 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------------------------------------------------
# projections: per-plane homographies
# ----------------------------------------------------------------------------------------------------------------------
def _apply_h(H, xy):
    p = xy @ H[:, :2].T + H[:, 2]
    return p[:, :2] / p[:, 2:]


def _homography(xy, uv):
    """Homography ``uv ~ H (x, y, 1)`` from >= 4 point pairs (OpenCV's plain least-squares fit, exact for 4).

    (``dlt.homography_dlt`` takes the last row of the thin SVD, which for exactly 4 points - 8 equations, 9 unknowns -
    is not the null vector.)
    """
    H, _ = cv2.findHomography(np.asarray(xy, np.float64), np.asarray(uv, np.float64), 0)
    if H is None:
        raise ValueError("outer corners: degenerate (collinear) points, no homography")
    return H


def _plane_homographies_from_P(geometry, P):
    """Homography ``uv ~ H (x, y, 1)`` of each plane from a projection ``P (3, 4)`` of the board frame (Eq. 54)."""
    return [P @ plane.T_board_plane[:, [0, 1, 3]] for plane in geometry.planes]


def _check_P(P):
    P = np.asarray(P, dtype=float)
    if P.shape != (3, 4):
        raise ValueError(f"initial_P: expected shape (3, 4), got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("initial_P: contains NaN or inf")
    if np.linalg.matrix_rank(P) < 3:
        raise ValueError("initial_P: rank < 3, not a projection matrix")
    return P


def _homographies_from_outer(geometry, outer_uv):
    """Initial projection from the hand-clicked outer corners (§3.3.3): DLT (Eq. 55-58) or a homography."""
    outer_uv = np.asarray(outer_uv, dtype=float)
    X = geometry.outer_points
    if outer_uv.shape != X.shape[:1] + (2,):
        raise ValueError(f"outer_corners_uv: expected shape ({len(X)}, 2) for the {geometry.name} geometry, "
                         f"got {outer_uv.shape}")
    if not np.all(np.isfinite(outer_uv)):
        raise ValueError("outer_corners_uv: contains NaN or inf")
    if dlt.is_planar(X):
        T = dlt.plane_frame(X)
        xy = (X - T[:3, 3]) @ T[:3, :3]
        H = _homography(xy[:, :2], outer_uv)  # uv ~ H (x, y, 1) in the frame of the outer points
        # the same mapping as a 3x4 projection of the board frame: (x, y) = first two plane coordinates of X
        Tinv = np.linalg.inv(T)
        P = H @ Tinv[[0, 1, 3], :]
    else:
        P = dlt.dlt_projection_matrix(X, outer_uv)  # Eq. 55-58
    return _plane_homographies_from_P(geometry, P)


# ----------------------------------------------------------------------------------------------------------------------
# edges: smoothing, Sobel, non-maximum suppression (Eq. 88-91, §3.3.4)
# ----------------------------------------------------------------------------------------------------------------------
@dataclass
class EdgeMap:
    """Edge points of an image after non-maximum suppression.

    ``uv (K, 2)`` sub-pixel positions (px), ``pixel (K, 2)`` integer positions, ``magnitude (K,)`` (Eq. 90),
    ``normal (K, 2)`` unit gradient directions (Eq. 91), ``binary (H, W)`` the map of Figure 24, ``threshold``.
    """

    uv: np.ndarray
    pixel: np.ndarray
    magnitude: np.ndarray
    normal: np.ndarray
    binary: np.ndarray
    threshold: float


def edge_map(image, sigma: float = 1.0, threshold: float = 0.15, subpixel: bool = True) -> EdgeMap:
    """Edge points by Gaussian smoothing, Sobel gradients and non-maximum suppression (§3.3.4).

    Parameters
    ----------
    image : array (H, W) or (H, W, 3)
        Grey or BGR image.
    sigma : float
        Standard deviation of the Gaussian smoothing (px); 0 for none.
    threshold : float
        Edge points must have a magnitude above ``threshold`` times the 99.9th percentile of the magnitude.
    subpixel : bool
        Refine each edge point by the vertex of the parabola through the magnitudes of it and its two neighbours along
        the quantised direction (an addition to the thesis, which keeps integer pixels).
    """
    g = check_image(image)
    if sigma > 0:
        g = cv2.GaussianBlur(g, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    gx = cv2.filter2D(g, cv2.CV_64F, SOBEL_X, borderType=cv2.BORDER_REPLICATE)  # Eq. 88
    gy = cv2.filter2D(g, cv2.CV_64F, SOBEL_Y, borderType=cv2.BORDER_REPLICATE)  # Eq. 89
    mag = np.hypot(gx, gy)  # Eq. 90
    theta = np.arctan2(gy, gx)  # Eq. 91 (four-quadrant)
    sector = np.mod(np.rint(theta / (np.pi / 4)).astype(int), 4)  # Figure 23: 0, 45, 90, 135 degrees
    ref = np.percentile(mag, 99.9)
    thr = threshold * ref
    h, w = mag.shape
    pad = np.pad(mag, 1, mode="constant")
    m_minus = np.zeros_like(mag)
    m_plus = np.zeros_like(mag)
    for k, (du, dv) in enumerate(DIRECTIONS):
        plus = pad[1 + dv:1 + dv + h, 1 + du:1 + du + w]
        minus = pad[1 - dv:1 - dv + h, 1 - du:1 - du + w]
        sel = sector == k
        m_plus[sel] = plus[sel]
        m_minus[sel] = minus[sel]
    # a maximum along the quantised direction (ties broken to one side so a plateau gives one pixel), above threshold
    keep = (mag >= m_plus) & (mag > m_minus) & (mag > thr)
    keep[0, :] = keep[-1, :] = keep[:, 0] = keep[:, -1] = False
    v, u = np.nonzero(keep)
    m0 = mag[v, u]
    step = DIRECTIONS[sector[v, u]].astype(float)
    offset = np.zeros_like(m0)
    if subpixel:
        a, c = m_minus[v, u], m_plus[v, u]
        den = a - 2.0 * m0 + c
        ok = den < 0
        offset[ok] = np.clip(0.5 * (a[ok] - c[ok]) / den[ok], -0.5, 0.5)
    pix = np.column_stack([u, v]).astype(float)
    uv = pix + offset[:, None] * step
    normal = np.column_stack([gx[v, u], gy[v, u]]) / m0[:, None]
    return EdgeMap(uv, pix.astype(int), m0, normal, keep, float(thr))


# ----------------------------------------------------------------------------------------------------------------------
# k-means line fitting (Eq. 92-93)
# ----------------------------------------------------------------------------------------------------------------------
def fit_line_tls(points):
    """Line ``a u + b v + c = 0`` with ``a^2 + b^2 = 1`` through ``points (K, 2)`` by total least squares.

    The normal ``(a, b)`` is the eigenvector of the smallest eigenvalue of the scatter matrix (Eq. 92), ``c`` from the
    centroid (Eq. 93). Returns ``(3,)``.
    """
    p = np.asarray(points, dtype=float)
    mean = p.mean(axis=0)
    d = p - mean
    C = d.T @ d / len(p)  # [[x2 - x x, xy - x y], [xy - x y, y2 - y y]] of Eq. 92, centred for accuracy
    w, V = np.linalg.eigh(C)
    a, b = V[:, 0]  # smallest eigenvalue; unit norm
    return np.array([a, b, -a * mean[0] - b * mean[1]])  # Eq. 93


def intersect_lines(l1, l2):
    """Intersection ``(..., 2)`` of lines ``(..., 3)`` (``a u + b v + c = 0``); NaN when parallel."""
    p = np.cross(l1, l2)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = p[..., :2] / p[..., 2:]
    return np.where(np.abs(p[..., 2:]) > 1e-12 * np.linalg.norm(p[..., :2], axis=-1, keepdims=True), out, np.nan)


def kmeans_lines(points, normals, lines0, gate_px, angle_tol_deg=30.0, max_iterations=20, min_points=6):
    """k-means line fitting (§3.3.5): assign each point to the nearest line, refit each line (Eq. 92-93), repeat.

    Stops when the assignment is the same in two consecutive iterations (the thesis's criterion) or after
    ``max_iterations`` (an assignment can flip-flop between two states for a point at the gate). Points farther than
    ``gate_px`` from every line, or whose gradient ``normals`` is more than ``angle_tol_deg`` away from the line's
    normal, are left unassigned (additions that keep stray edges out).

    Parameters
    ----------
    points, normals : arrays (K, 2)
        Edge points (px) and their unit gradient directions.
    lines0 : array (L, 3)
        Initial lines ``a u + b v + c = 0``, ``a^2 + b^2 = 1``.

    Returns
    -------
    lines : ndarray (L, 3)
    labels : ndarray (K,)
        Line index of each point, -1 when unassigned.
    iterations : int
    converged : bool
        The assignment settled.
    enough : bool
        Every line kept at least ``min_points`` points (otherwise ``lines`` are the last valid ones).
    """
    lines = np.array(lines0, dtype=float)
    labels = None
    cos_tol = np.cos(np.radians(angle_tol_deg))
    for it in range(1, max_iterations + 1):
        dist = np.abs(points @ lines[:, :2].T + lines[:, 2])  # (K, L)
        align = np.abs(normals @ lines[:, :2].T) >= cos_tol
        dist = np.where(align, dist, np.inf)
        new = np.argmin(dist, axis=1)
        new[np.min(dist, axis=1) > gate_px] = -1
        if labels is not None and np.array_equal(new, labels):
            return lines, labels, it - 1, True, True
        labels = new
        for k in range(len(lines)):
            sel = labels == k
            if sel.sum() < min_points:
                return lines, labels, it, False, False
            lines[k] = fit_line_tls(points[sel])
    return lines, labels, max_iterations, False, True


def _line_through(p, direction):
    n = np.array([-direction[1], direction[0]]) / np.linalg.norm(direction)
    return np.array([n[0], n[1], -n @ p])


# ----------------------------------------------------------------------------------------------------------------------
# OpenCV detection per plane and canonical labelling
# ----------------------------------------------------------------------------------------------------------------------
def _subpix(gray_u8, uv, inner):
    """``cv2.cornerSubPix`` with a half-window of a quarter of the median corner spacing (2..15 px)."""
    nx, ny = inner
    g = uv.reshape(ny, nx, 2)
    spacing = np.median(np.concatenate([np.linalg.norm(np.diff(g, axis=1), axis=2).ravel(),
                                        np.linalg.norm(np.diff(g, axis=0), axis=2).ravel()]))
    half = int(np.clip(round(0.25 * spacing), 2, 15))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    c = cv2.cornerSubPix(gray_u8, uv.reshape(-1, 1, 2).astype(np.float32), (half, half), (-1, -1), crit)
    return c.reshape(-1, 2).astype(float)


def grid_outliers(uv, inner, tol: float = 0.2) -> np.ndarray:
    """Corners of a detected grid that break its regularity: mask ``(nx * ny,)``.

    A misplaced corner ``c1`` makes the second difference ``c0 - 2 c1 + c2`` of the triples of its row and column
    large, and also their third difference ``c0 - 3 c1 + 3 c2 - c3``; perspective and lens distortion make the
    second differences grow smoothly along a row (near the border of a strongly distorted image they reach 0.2 of
    the corner spacing) while the third differences stay small (<= 0.06 of the spacing for Table 9's distortion).
    A corner is flagged when a triple it belongs to has a second difference above ``tol`` times the median corner
    spacing and a quadruple it belongs to a third difference above the same bound (rows or columns of fewer than
    four corners: the second difference alone).
    """
    nx, ny = inner
    g = np.asarray(uv, dtype=float).reshape(ny, nx, 2)
    spacing = np.median(np.concatenate([np.linalg.norm(np.diff(g, axis=1), axis=2).ravel(),
                                        np.linalg.norm(np.diff(g, axis=0), axis=2).ravel()]))
    limit = tol * spacing

    def along_rows(h):  # flags (rows, n) for the rows of h (rows, n, 2)
        n = h.shape[1]
        second = np.zeros(h.shape[:2], dtype=bool)
        if n < 3:
            return second
        e = np.linalg.norm(h[:, :-2] - 2 * h[:, 1:-1] + h[:, 2:], axis=2) > limit
        for k in range(3):
            second[:, k:n - 2 + k] |= e
        if n < 4:
            return second
        third = np.zeros_like(second)
        e = np.linalg.norm(h[:, :-3] - 3 * h[:, 1:-2] + 3 * h[:, 2:-1] - h[:, 3:], axis=2) > limit
        for k in range(4):
            third[:, k:n - 3 + k] |= e
        return second & third

    bad = along_rows(g) | along_rows(g.transpose(1, 0, 2)).T
    return bad.ravel()


def _detect_grid(gray_u8, inner, accuracy=True, subpix=True):
    """One chessboard with ``inner`` corners: ``(uv (n, 2), detector)`` or ``(None, reason)``.

    ``findChessboardCornersSB`` first; when it finds nothing, or a grid with a misplaced corner (it can return one,
    e.g. 27 px off on one of the real webcam photos), ``findChessboardCorners``.
    """
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE
    if accuracy:
        flags |= cv2.CALIB_CB_ACCURACY
    # The SB detector draws from OpenCV's process-wide RNG (cv::theRNG), so without a seed its corners depend on
    # what ran before in the process (measured: 0.1 px on one x-y table view, enough to move a run's result).
    # Seeding it with OpenCV's default state makes every call what the first call of a fresh process gives.
    cv2.setRNGSeed(CV_RNG_SEED)
    ok, c = cv2.findChessboardCornersSB(gray_u8, inner, flags=flags)
    how = "findChessboardCornersSB"
    reasons = ["findChessboardCornersSB found no board"]
    if ok and grid_outliers(c.reshape(-1, 2), inner).any():
        ok, reasons = False, ["findChessboardCornersSB returned an irregular grid"]
    if not ok:
        ok, c = cv2.findChessboardCorners(gray_u8, inner,
                                          flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        how = "findChessboardCorners"
        if not ok:
            return None, " and ".join(reasons + ["findChessboardCorners found no board"])
        subpix = True  # the quad detector's corners are pixel-accurate only
    uv = c.reshape(-1, 2).astype(float)
    if subpix:
        uv = _subpix(gray_u8, uv, inner)
        how += "+cornerSubPix"
    if grid_outliers(uv, inner).any():
        return None, f"{how} returned an irregular grid (a misplaced corner)"
    return uv, how


def _mask_grid(gray_u8, uv, inner):
    """Paint the detected board (its corner hull grown by one square) with the image median."""
    nx, ny = inner
    g = uv.reshape(ny, nx, 2)
    quad = np.array([g[0, 0], g[0, -1], g[-1, -1], g[-1, 0]])
    H = cv2.getPerspectiveTransform(np.array([[0, 0], [nx - 1, 0], [nx - 1, ny - 1], [0, ny - 1]], np.float32),
                                    quad.astype(np.float32))
    grown = np.array([[-1.2, -1.2], [nx + 0.2, -1.2], [nx + 0.2, ny + 0.2], [-1.2, ny + 0.2]])
    poly = _apply_h(H, grown)
    out = gray_u8.copy()
    cv2.fillConvexPoly(out, np.rint(poly).astype(np.int32), int(np.median(gray_u8)))
    return out


def _grid_symmetries(inner):
    """Relabellings of an ``(ny, nx)`` grid array that keep its shape: functions ``G (ny, nx, 2) -> (ny, nx, 2)``."""
    nx, ny = inner
    ops = [lambda g: g, lambda g: g[::-1, ::-1], lambda g: g[::-1, :], lambda g: g[:, ::-1]]
    if nx == ny:
        ops += [lambda g: np.swapaxes(g, 0, 1), lambda g: np.swapaxes(g, 0, 1)[::-1, ::-1],
                lambda g: np.swapaxes(g, 0, 1)[::-1, :], lambda g: np.swapaxes(g, 0, 1)[:, ::-1]]
    return ops


def _signed_area(g):
    quad = np.array([g[0, 0], g[0, -1], g[-1, -1], g[-1, 0]])
    x, y = quad[:, 0], quad[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def _proper_labellings(uv, inner):
    """The labellings of a detected grid that are not mirrored (positive signed area in u-right, v-down pixels)."""
    nx, ny = inner
    g = uv.reshape(ny, nx, 2)
    return [h.reshape(-1, 2) for h in (op(g) for op in _grid_symmetries(inner)) if _signed_area(h) > 0]


def canonical_labelling(geometry: BoardGeometry, detections):
    """Assign unlabelled per-plane detections to the geometry's corner ids (see *Ordering* in the module docstring).

    Parameters
    ----------
    geometry : BoardGeometry
    detections : list of arrays (n_p, 2)
        One grid per plane, in any of its symmetric labellings and any plane order (row-major as OpenCV returns).

    Returns
    -------
    uv : ndarray (N, 2) in id order, or None
    message : str
    """
    planes = geometry.planes
    if len(detections) != len(planes):
        return None, f"{len(detections)} board(s) detected for {len(planes)} plane(s)"
    X = geometry.object_points()
    candidates = []  # (uv (N, 2), residual)
    for perm in itertools.permutations(range(len(planes))):
        if any(len(detections[perm[p]]) != planes[p].inner[0] * planes[p].inner[1] for p in range(len(planes))):
            continue
        options = [_proper_labellings(detections[perm[p]], plane.inner) for p, plane in enumerate(planes)]
        for combo in itertools.product(*options):
            uv = np.vstack(combo)
            if len(planes) == 1:
                candidates.append((uv, 0.0))
                continue
            try:
                M = dlt.dlt_projection_matrix(X, uv)  # Eq. 55-58 on all planes at once
            except ValueError:
                continue
            depth = X @ M[2, :3] + M[2, 3]
            if np.all(depth > 0):  # det(M[:, :3]) > 0 and positive depths: not mirrored, in front of the camera
                candidates.append((uv, dlt.reprojection_rms(M, X, uv)))
    if not candidates:
        return None, "no labelling of the detected grids is consistent with the board geometry"
    best = min(c[1] for c in candidates)
    tol = max(3.0 * best, 1.0)  # a wrong labelling of a rig misfits by a good fraction of a square
    good = [c[0] for c in candidates if c[1] <= tol]
    first = np.array([np.hypot(*c[0]) for c in good])  # id 0 nearest the image's top-left pixel
    return good[int(np.argmin(first))], f"labelling: {len(good)} consistent of {len(candidates)}, rms {best:.3g} px"


def _detect_planes(gray_u8, geometry, accuracy=True, subpix=True):
    """Detect every plane of the geometry with OpenCV (masking each found board) and label canonically."""
    work = gray_u8
    detections, detectors = [], []
    for plane in geometry.planes:
        uv, how = _detect_grid(work, plane.inner, accuracy, subpix)
        if uv is None:
            return None, f"plane {len(detections) + 1} of {len(geometry.planes)}: {how}", detectors
        detections.append(uv)
        detectors.append(how)
        work = _mask_grid(work, uv, plane.inner)
    uv, msg = canonical_labelling(geometry, detections)
    return uv, msg, detectors


# ----------------------------------------------------------------------------------------------------------------------
# public extractors
# ----------------------------------------------------------------------------------------------------------------------
#: the extractors by name: OpenCV's, the thesis's (sub-pixel edges: the bench's addition), the thesis's as printed
#: (lines fitted to the binary edge map's whole pixels, section 3.3.4-3.3.5)
EXTRACTORS = ("opencv", "thesis", "thesis_printed")


def extract_corners(image, board_geometry, extractor: str = "thesis", camera=None) -> CornerResult:
    """The corners of ``board_geometry`` in ``image`` by ``extractor`` (:data:`EXTRACTORS`):
    :func:`extract_corners_opencv` or :func:`extract_corners_thesis` (``camera``: thesis extractors only). ValueError
    for an unknown name."""
    if extractor not in EXTRACTORS:
        raise ValueError(f"extractor: expected one of {', '.join(EXTRACTORS)}, got {extractor!r}")
    if extractor == "opencv":
        if camera is not None:
            raise ValueError("camera: only the thesis extractor fits lines in ideal pixels")
        return extract_corners_opencv(image, board_geometry)
    return extract_corners_thesis(image, board_geometry, camera=camera, subpixel=extractor == "thesis")


def extract_corners_opencv(image, board=(7, 7), accuracy: bool = True, subpix: bool = True) -> CornerResult:
    """OpenCV corners: ``findChessboardCornersSB`` (fallback ``findChessboardCorners`` + ``cornerSubPix``).

    Parameters
    ----------
    image : array (H, W) or (H, W, 3)
        Grey or BGR image.
    board : (nx, ny) or BoardGeometry
        Inner corners of a planar board (unit squares), or a geometry (e.g. :func:`two_plane_rig`): each plane is
        detected separately.
    accuracy : bool
        Pass ``CALIB_CB_ACCURACY`` to the SB detector.
    subpix : bool
        Refine the SB corners with ``cv2.cornerSubPix`` (half-window a quarter of the corner spacing); the SB corners
        alone are good to 0.1-0.5 px on the synthetic images of the tests, refined to about 0.05 px. The fallback
        detector's corners are always refined.

    Returns
    -------
    CornerResult
        Corners in canonical order; ``success=False`` with the reason when a plane is not found.
    """
    geometry = _as_geometry(board)
    gray = check_image(image)
    uv, msg, detectors = _detect_planes(_to_uint8(gray), geometry, accuracy, subpix)
    method = "opencv: " + ", ".join(detectors)
    if uv is None:
        return _failure(msg, method)
    n = geometry.n_corners
    return CornerResult(True, f"{n} corners; {msg}", uv, geometry.object_points(), np.arange(n),
                        np.full((n, 2, 3), np.nan), 0, method, "", np.full(n, np.nan))


def extract_corners_thesis(image, board_geometry=(7, 7), initial_P=None, outer_corners_uv=None, *,
                           sigma: float = 1.0, threshold: float = 0.15, window: float = 0.7, inner_px: float = 3.0,
                           gate: float = 0.2, final_gate_px: float = 1.5, angle_tol_deg: float = 30.0,
                           local_threshold: float = 0.4,
                           max_iterations: int = 20, subpixel: bool = True, camera=None) -> CornerResult:
    """Corners by non-maximum suppression and k-means line fitting (§3.3.3-3.3.5).

    Parameters
    ----------
    image : array (H, W) or (H, W, 3)
        Grey or BGR image.
    board_geometry : BoardGeometry or (nx, ny)
        The target (:func:`planar_board`, :func:`two_plane_rig`); a pair means a planar board with unit squares.
    initial_P : array (3, 4), optional
        Rough projection matrix of the board frame (Eq. 54) giving the predicted corners and lines.
    outer_corners_uv : array (M, 2), optional
        The hand-clicked outer corners, in the order of ``board_geometry.outer_points`` (used when ``initial_P`` is
        not given). Without either, the initial projection is found automatically (module docstring).
    sigma, threshold, subpixel
        Edge map parameters (:func:`edge_map`).
    window : float
        Radius of the window around each corner, in local square sides.
    inner_px : float
        Radius (px, at least ``2 sigma + 1``) of the disk around the corner whose edge points are not used.
    gate : float
        First-pass gate (square sides): edge points farther from both lines are not assigned; the second pass (window
        re-centred on the first estimate) uses ``final_gate_px``.
    angle_tol_deg : float
        Largest angle between an edge point's gradient and the normal of the line it is assigned to.
    local_threshold : float
        In each window only edge points stronger than this fraction of the window's 90th-percentile magnitude count.
    max_iterations : int
        Per k-means run.
    camera : CameraModel, optional
        A calibration of the camera (e.g. a first pass with corners extracted without it). The edge points are then
        mapped to ideal pixels ``K undistort(K^-1 uv)`` (their gradient directions through the local Jacobian of the
        distortion) and the lines are fitted there, where the board's lines are straight; each corner found is
        mapped back through the camera's distortion. Without it the lines are fitted in the image, where a
        distorted board line is curved and the intersection of the two locally straight fits is biased along the
        curvature (outwards under pincushion: 0.09 px at 250 px from the centre with Table 9's distortion, which
        biases the focal length by ~0.1 %; an addition to the thesis).

    Returns
    -------
    CornerResult
        ``uv`` in canonical order (id order of the geometry), the two fitted lines per corner (in ideal pixels when
        ``camera`` is given), the k-means iterations.
    """
    geometry = _as_geometry(board_geometry)
    gray = check_image(image)
    ideal = None if camera is None else _IdealDomain(camera, gray.shape[::-1])
    method = "thesis: NMS + k-means lines"
    if initial_P is not None:
        Hs = _plane_homographies_from_P(geometry, _check_P(initial_P))
        init = "initial_P"
    elif outer_corners_uv is not None:
        Hs = _homographies_from_outer(geometry, outer_corners_uv)
        init = "manual outer corners"
    else:
        uv_cv, msg, detectors = _detect_planes(_to_uint8(gray), geometry, accuracy=False, subpix=False)
        if uv_cv is None:
            return _failure(f"automatic initialisation failed: {msg}", method, "automatic")
        Hs = []
        for plane, sl in zip(geometry.planes, geometry.plane_slices(), strict=True):
            nx, ny = plane.inner
            idx = np.array([0, nx - 1, nx * ny - 1, nx * (ny - 1)])  # the plane's four extreme corners only
            xy = plane.points_plane()[idx, :2]
            Hs.append(_homography(xy, uv_cv[sl][idx]))
        init = "automatic: " + ", ".join(detectors) + " outer corners"
    edges = edge_map(gray, sigma, threshold, subpixel)
    if len(edges.uv) < 10:
        return _failure("no edges above the threshold (blank image?)", method, init)
    h, w = gray.shape

    def inside(c, r):  # the window of radius r around c lies in the image
        return r <= c[0] <= w - 1 - r and r <= c[1] <= h - 1 - r

    to_image = None
    if ideal is not None:
        edges, Hs = ideal.edges(edges), [ideal.homography(geometry, plane, H) for plane, H in
                                         zip(geometry.planes, Hs, strict=True)]
        inside, to_image = ideal.window_inside, ideal.to_image
        method += " (lines in ideal pixels)"
    r_in = max(inner_px, 2.0 * sigma + 1.0)
    uv_all, lines_all, rms_all, iters, failed = [], [], [], 0, []
    for plane, H in zip(geometry.planes, Hs, strict=True):
        xy = plane.points_plane()[:, :2]
        s = plane.square
        c0 = _apply_h(H, xy)
        # image directions of the two board lines through each corner, and the local square size (px)
        du = _apply_h(H, xy + [s, 0]) - _apply_h(H, xy - [s, 0])
        dv = _apply_h(H, xy + [0, s]) - _apply_h(H, xy - [0, s])
        side = 0.5 * np.minimum(np.linalg.norm(du, axis=1), np.linalg.norm(dv, axis=1))
        for k in range(len(xy)):
            res = _corner_from_edges(edges, c0[k], du[k], dv[k], side[k], window, r_in, gate, final_gate_px,
                                     angle_tol_deg, max_iterations, inside, local_threshold)
            if res is None:
                failed.append(len(uv_all))
            p, lines, rms, it = res or (np.full(2, np.nan), np.full((2, 3), np.nan), np.nan, 0)
            uv_all.append(p)
            lines_all.append(lines)
            rms_all.append(rms)
            iters = max(iters, it)
    n = geometry.n_corners
    uv = np.array(uv_all)
    if to_image is not None and not failed:
        uv = to_image(uv)
    if failed:
        more = "..." if len(failed) > 10 else ""
        return _failure(f"{len(failed)} of {n} corners not found (ids {failed[:10]}{more})", method, init, iters)
    return CornerResult(True, f"{n} corners", uv, geometry.object_points(), np.arange(n), np.array(lines_all), iters,
                        method, init, np.array(rms_all))


class _IdealDomain:
    """Ideal (undistorted) pixels ``K undistort(K^-1 uv)`` of a calibrated camera (:func:`extract_corners_thesis`)."""

    def __init__(self, camera, size):
        from bench.camera.model import CameraModel

        if not isinstance(camera, CameraModel):
            raise ValueError(f"camera: expected a CameraModel, got {type(camera).__name__}")
        if camera.size != tuple(size):
            raise ValueError(f"camera: its image size {camera.size} differs from the image's {tuple(size)}")
        self.camera = camera

    def to_ideal(self, uv):
        from bench.camera.model import to_pixels

        return to_pixels(self.camera.undistort_pixels(uv), self.camera.K)

    def to_image(self, uv_ideal):
        from bench.camera.model import distort, from_pixels, to_pixels

        return to_pixels(distort(from_pixels(uv_ideal, self.camera.K), self.camera.dist), self.camera.K)

    def edges(self, e: EdgeMap) -> EdgeMap:
        """The edge points in ideal pixels; normals ``J^T n`` (``J`` = d image / d ideal pixels), renormalised."""
        from bench.camera.model import distortion_jacobian, from_pixels

        uv = self.to_ideal(e.uv)
        K2 = self.camera.K[:2, :2]
        D = distortion_jacobian(from_pixels(uv, self.camera.K), self.camera.dist)
        J = K2 @ D @ np.linalg.inv(K2)  # (K, 2, 2)
        n = np.einsum("kji,kj->ki", J, e.normal)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        ok = np.all(np.isfinite(uv), axis=1) & np.all(np.isfinite(n), axis=1)
        return EdgeMap(uv[ok], e.pixel[ok], e.magnitude[ok], n[ok], e.binary, e.threshold)

    def homography(self, geometry, plane, H):
        """The plane's homography in ideal pixels from its four extreme predicted corners (exact for a pinhole)."""
        nx, ny = plane.inner
        idx = np.array([0, nx - 1, nx * ny - 1, nx * (ny - 1)])
        xy = plane.points_plane()[idx, :2]
        return _homography(xy, self.to_ideal(_apply_h(H, xy)))

    def window_inside(self, c, r):
        """The window of radius ``r`` (ideal px) around ``c`` maps inside the image."""
        a = np.linspace(0, 2 * np.pi, 8, endpoint=False)
        uv = self.to_image(c + r * np.column_stack([np.cos(a), np.sin(a)]))
        return bool(self.camera.in_image(uv, border=0.5).all())


def _corner_from_edges(edges, c0, du, dv, side, window, r_in, gate, final_gate_px, angle_tol_deg, max_iterations,
                       inside, local_threshold):
    """One corner: two k-means passes on the edge points around the prediction ``c0``; None when it fails."""
    if not (np.all(np.isfinite(c0)) and side > 2.0 * r_in):
        return None
    r_out = window * side
    if not inside(c0, r_out):
        return None  # the window leaves the image
    lines = np.array([_line_through(c0, du), _line_through(c0, dv)])
    centre = c0
    total = 0
    for gate_px in (max(gate * side, 2.0), final_gate_px):
        d = np.linalg.norm(edges.uv - centre, axis=1)
        sel = (d > r_in) & (d < r_out)
        if sel.sum() < 12:
            return None
        # local threshold: the board lines are the window's strongest edges (keeps out print and JPEG ghost edges,
        # e.g. the lighter interior of a printed black square)
        sel &= edges.magnitude >= local_threshold * np.percentile(edges.magnitude[sel], 90)
        pts, nrm = edges.uv[sel], edges.normal[sel]
        if len(pts) < 12:
            return None
        lines, labels, it, _, enough = kmeans_lines(pts, nrm, lines, gate_px, angle_tol_deg, max_iterations)
        total += it
        if not enough:
            return None
        p = intersect_lines(lines[0], lines[1])
        if not np.all(np.isfinite(p)) or np.linalg.norm(p - c0) > 0.5 * r_out:
            return None
        centre = p
    # the two lines must cross at a sensible angle (a chessboard corner, not two edges of one stripe)
    if abs(lines[0, :2] @ lines[1, :2]) > np.cos(np.radians(20.0)):
        return None
    sel = labels >= 0
    dist = np.abs(np.sum(pts[sel] * lines[labels[sel], :2], axis=1) + lines[labels[sel], 2])
    return p, lines, float(np.sqrt(np.mean(dist**2))), total
