"""Camera-mount (hand-eye) calibration: where the camera sits on link 5 (or on the x-y table's carriage).

Two approaches, compared by the scenarios:

* :func:`hand_eye_axxb` - the proper ``AX = XB`` solution from rig views: mount poses ``T_base_mount`` from the arm
  kinematics (or table readings) and target poses ``T_cam_target`` from the calibrated camera's extrinsics give
  ``X = T_mount_cam``. Closed-form initial solutions - Park & Martin (1994: rotation from the log-maps of the
  relative motions, translation by linear least squares) and Andreff et al. (2001: the linear Kronecker form) - then
  a joint least-squares refinement of ``X`` and the (constant) target pose over all views. OpenCV's
  ``calibrateHandEye`` would be the natural reference, but the opencv-python 5.0.0.93 wheels lack its binding
  (opencv/opencv#29565, fixed upstream after that release); where it exists the tests compare against it.
* :func:`search_mount_rotation` - the thesis's search (section 5.2.2, Eq. 197-198): the mount rotation
  ``R0 = Ry(theta_y0) Rx(theta_x0) Rz(theta_z0)`` is not measured but found from the keypoints themselves:
  ``theta_y0`` so that the points triangulated against the leftmost and the rightmost view have the same mean depth,
  ``theta_z0`` so that the most viewing rays coincide within ``coincide_m`` (thesis: 1 mm), ``theta_x0`` left at
  0 when there is no motion along y. Eq. 197's middle and last factors are printed as a rotation about z labelled
  ``theta_x0`` and one about x labelled ``theta_z0``; the text (``theta_z0`` is "the offset angle in the image
  plane", i.e. about the optical axis z) says the labels are right and the matrices swapped - the same misprint as
  Eq. 190 (``bench.robot.orientation``) - so the factors are applied as labelled. Ties of the ray count (a plateau
  around the optimum, since a small roll moves rays near the image centre by less than ``coincide_m``) are broken
  by the smallest median closest-approach distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from bench.geometry.quaternion import matrix_to_rotation_vector, rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert, rot_x, rot_y, rot_z, rotation_angle
from bench.vision.features import match_features
from bench.vision.triangulation import triangulate_midpoint

METHODS = ("park", "andreff")


@dataclass(frozen=True)
class HandEyeResult:
    """Outcome of :func:`hand_eye_axxb`.

    ``T_mount_cam`` the camera in the mount (link-5) frame; ``T_base_target`` the rig in the base frame (from the
    refinement); ``rms_rot_rad`` / ``rms_trans_m`` the residuals of ``T_base_mount X T_cam_target = T_base_target``
    over the views; ``condition`` of the rotation problem (spread of the relative rotation axes; large = too little
    rotation diversity).
    """

    success: bool
    message: str
    T_mount_cam: np.ndarray
    T_base_target: np.ndarray
    rms_rot_rad: float
    rms_trans_m: float
    condition: float
    method: str


def _check_stack(T, name):
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: expected finite (N, 4, 4) transforms, got shape {T.shape}")
    return T


def _relative_motions(A, B):
    """``A_k = A_(k+1)^-1 A_k`` and ``B_k = B_(k+1) B_k^-1``: from ``A_k X B_k = const`` follows ``A_k X = X B_k``."""
    return invert(A[1:]) @ A[:-1], B[1:] @ invert(B[:-1])


def _translation(Ar, Br, R):
    """Least squares ``(R_A - I) t = R t_B - t_A`` over the relative motions."""
    M = (Ar[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (np.einsum("ij,kj->ki", R, Br[:, :3, 3]) - Ar[:, :3, 3]).ravel()
    return np.linalg.lstsq(M, rhs, rcond=None)[0]


def _park(A, B):
    """Park & Martin: ``R = (M^T M)^-1/2 M^T`` with ``M = sum beta_k alpha_k^T`` (log-maps of the rotations)."""
    Ar, Br = _relative_motions(A, B)
    M = matrix_to_rotation_vector(Br[:, :3, :3]).T @ matrix_to_rotation_vector(Ar[:, :3, :3])  # sum_k beta_k alpha_k^T
    w, V = np.linalg.eigh(M.T @ M)
    R = V @ np.diag(1.0 / np.sqrt(w)) @ V.T @ M.T
    u, _, vt = np.linalg.svd(R)
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return homogeneous(R, _translation(Ar, Br, R))


def _andreff(A, B):
    """Andreff et al.: ``(I9 - R_A (x) R_B) vec(R) = 0`` (row-major vec) by SVD, then orthonormalised."""
    Ar, Br = _relative_motions(A, B)
    K = np.concatenate([np.eye(9) - np.kron(a[:3, :3], b[:3, :3]) for a, b in zip(Ar, Br, strict=True)])
    R = np.linalg.svd(K)[2][-1].reshape(3, 3)
    R /= np.cbrt(np.linalg.det(R))
    u, _, vt = np.linalg.svd(R)
    R = u @ vt
    return homogeneous(R, _translation(Ar, Br, R))


def hand_eye_axxb(T_base_mount, T_cam_target, method: str = "park", refine: bool = True) -> HandEyeResult:
    """Solve ``A X = X B`` for the camera mount ``X = T_mount_cam``.

    Parameters
    ----------
    T_base_mount : array_like (N, 4, 4)
        Mount (link 5, or the table carriage) poses from the joint / table readings.
    T_cam_target : array_like (N, 4, 4)
        The calibration target seen from the camera (extrinsics of the calibrated camera), same views.
    method : {"park", "andreff"}
        Closed-form initial solution.
    refine : bool
        Refine ``X`` and ``T_base_target`` jointly by least squares on all views.
    """
    A = _check_stack(T_base_mount, "T_base_mount")
    B = _check_stack(T_cam_target, "T_cam_target")
    if len(A) != len(B):
        raise ValueError(f"T_base_mount and T_cam_target: {len(A)} vs {len(B)} views")
    if method not in METHODS:
        raise ValueError(f"method: expected one of {sorted(METHODS)}, got {method!r}")
    nan = np.full((4, 4), np.nan)
    if len(A) < 3:
        return HandEyeResult(False, f"{len(A)} views; AX = XB needs >= 3 with two non-parallel rotation axes", nan,
                             nan, np.nan, np.nan, np.inf, method)
    # rotation diversity: relative rotation axes between consecutive views
    axes = matrix_to_rotation_vector(A[0, :3, :3].T @ A[1:, :3, :3])
    sv = np.linalg.svd(axes, compute_uv=False)
    condition = float(sv[0] / sv[1]) if sv[1] > 1e-12 else np.inf
    if not np.isfinite(condition) or condition > 1e6:
        return HandEyeResult(False, "the mount rotated about a single axis only: X is not determined (need two "
                                    "non-parallel rotation axes)", nan, nan, np.nan, np.nan, condition, method)
    X = _park(A, B) if method == "park" else _andreff(A, B)
    T_bt = np.mean(A @ X @ B, axis=0)
    u, _, vt = np.linalg.svd(T_bt[:3, :3])
    T_bt = homogeneous(u @ vt, T_bt[:3, 3])

    def residual(x):
        Xk = homogeneous(rotation_vector_to_matrix(x[:3]), x[3:6])
        Tk = homogeneous(rotation_vector_to_matrix(x[6:9]), x[9:12])
        P = A @ Xk @ B  # predicted T_base_target per view
        rot = matrix_to_rotation_vector(Tk[:3, :3].T @ P[:, :3, :3])
        return np.concatenate([rot.ravel() * 1.0, (P[:, :3, 3] - Tk[:3, 3]).ravel()])

    if refine:
        x0 = np.concatenate([matrix_to_rotation_vector(X[:3, :3]), X[:3, 3], matrix_to_rotation_vector(T_bt[:3, :3]),
                             T_bt[:3, 3]])
        sol = least_squares(residual, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15)
        X = homogeneous(rotation_vector_to_matrix(sol.x[:3]), sol.x[3:6])
        T_bt = homogeneous(rotation_vector_to_matrix(sol.x[6:9]), sol.x[9:12])
    P = A @ X @ B
    rot = rotation_angle(np.swapaxes(T_bt[:3, :3], -1, -2) @ P[:, :3, :3])
    tr = np.linalg.norm(P[:, :3, 3] - T_bt[:3, 3], axis=1)
    msg = "ok" if condition < 1e3 else f"WARNING poorly spread rotations (condition {condition:.3g})"
    return HandEyeResult(True, msg, X, T_bt, float(np.sqrt(np.mean(rot**2))), float(np.sqrt(np.mean(tr**2))),
                         condition, method)


def resolve_target_symmetry(T_base_mount, T_cam_target, T_mount_cam_guess, symmetries):
    """Make the target frame consistent across views when the target looks the same after a symmetry.

    A symmetric target (e.g. the two-plane rig after a half turn) can be labelled differently from view to view, so
    each view's ``T_cam_target`` may be off by one of the target's symmetries ``S`` (``T_cam_target S``), which breaks
    ``AX = XB``. With a rough mount (the nominal one), each view predicts the target's pose in the base frame; per view
    the candidate ``T_cam_target S`` closest to the consensus (the medoid over views and candidates) is kept.

    Returns ``(T_cam_target (N, 4, 4) consistent, chosen symmetry index per view)``.
    """
    A = _check_stack(T_base_mount, "T_base_mount")
    B = _check_stack(T_cam_target, "T_cam_target")
    S = [np.eye(4)] + [np.asarray(s, dtype=float) for s in symmetries]
    cand = np.stack([A @ np.asarray(T_mount_cam_guess, float) @ B @ s for s in S], axis=1)  # (N, k, 4, 4)
    flat = cand.reshape(-1, 4, 4)

    def dist(T1, T2):
        return np.linalg.norm(T1[..., :3, 3] - T2[..., :3, 3], axis=-1) + 0.5 * rotation_angle(
            np.swapaxes(T1[..., :3, :3], -1, -2) @ T2[..., :3, :3])

    D = np.array([dist(cand, T).min(axis=1).sum() for T in flat])  # each view's best candidate's distance to T
    medoid = flat[int(np.argmin(D))]
    choice = np.argmin(dist(cand, medoid), axis=1)
    return np.stack([B[i] @ S[c] for i, c in enumerate(choice)]), choice


def _screw_invariants(T):
    """``(angle (rad), translation along the axis (m))`` of rigid motions ``(..., 4, 4)``: unchanged by conjugation
    ``X T X^-1``, so equal for a mount motion ``A_ij`` and the camera motion ``B_ij`` it causes (``A_ij X = X B_ij``).
    Below 1e-6 rad the axis is undefined and the translation's length stands in."""
    w = matrix_to_rotation_vector(np.asarray(T)[..., :3, :3].reshape(-1, 3, 3))
    angle = np.linalg.norm(w, axis=1)
    t = np.asarray(T)[..., :3, 3].reshape(-1, 3)
    along = np.where(angle > 1e-6, np.abs(np.sum(w * t, axis=1)) / np.maximum(angle, 1e-12),
                     np.linalg.norm(t, axis=1))
    return angle, along


def resolve_target_symmetry_screw(T_base_mount, T_cam_target, symmetries, length_m: float = 1.0):
    """:func:`resolve_target_symmetry` without a mount guess: the labelling of each view is chosen so that the
    camera's motions between views match the mount's in the two quantities ``AX = XB`` preserves (rotation angle and
    translation along the screw axis; Park & Martin 1994), whatever ``X`` is.

    Views are taken in order; view 0 keeps its labelling (the target frame's choice), and each later view takes the
    candidate ``T_cam_target S`` whose motions to all earlier views match best (angle mismatch in rad plus the
    along-axis mismatch divided by ``length_m``).

    Returns ``(T_cam_target (N, 4, 4) consistent, chosen symmetry index per view, worst angle mismatch (rad))``.
    """
    A = _check_stack(T_base_mount, "T_base_mount")
    B = _check_stack(T_cam_target, "T_cam_target")
    if len(A) != len(B):
        raise ValueError(f"T_base_mount and T_cam_target: {len(A)} vs {len(B)} views")
    S = [np.eye(4)] + [np.asarray(s, dtype=float) for s in symmetries]
    chosen, fixed, worst = [0], [B[0]], 0.0
    for j in range(1, len(A)):
        ang_a, d_a = _screw_invariants(invert(A[j]) @ A[:j])  # A_ji = A_j^-1 A_i, i < j
        costs, mismatch = [], []
        for s in S:
            Bj = B[j] @ s
            ang_b, d_b = _screw_invariants(Bj @ np.stack([invert(b) for b in fixed]))  # B_ji = B_j B_i^-1
            costs.append(float(np.sum(np.abs(ang_a - ang_b) + np.abs(d_a - d_b) / length_m)))
            mismatch.append(float(np.max(np.abs(ang_a - ang_b))))
        c = int(np.argmin(costs))
        chosen.append(c)
        fixed.append(B[j] @ S[c])
        worst = max(worst, mismatch[c])
    return np.stack(fixed), np.array(chosen), worst


def mount_rotation(theta_x0, theta_y0, theta_z0):
    """``R0`` of Eq. 197, ``Ry(theta_y0) Rx(theta_x0) Rz(theta_z0)`` (labels trusted; see the module note)."""
    return rot_y(theta_y0) @ rot_x(theta_x0) @ rot_z(theta_z0)  # Eq. 197, factors as labelled


@dataclass(frozen=True)
class MountSearchResult:
    """Outcome of :func:`search_mount_rotation`: the angles (rad) and the criterion curves of each 1D search."""

    theta_x0: float
    theta_y0: float
    theta_z0: float
    curve_y: tuple  # (angles rad, |mean depth left - right| m)
    curve_z: tuple  # (angles rad, number of coinciding rays)
    message: str


def search_mount_rotation(reference, views, T_base_mount_ref, T_base_mount, t_mount_cam, grid_y, grid_z,
                          left: int = 0, right: int = -1, coincide_m: float = 0.001, gap_max_m: float = 0.005,
                          ratio: float = 0.8, orientation_tol_deg: float = 20.0,
                          depth_statistic: str = "mean", theta_z0_during_y: float = 0.0) -> MountSearchResult:
    """The thesis's search for the mount rotation (section 5.2.2).

    Parameters
    ----------
    reference : ViewObservation
        The reference view (``T_base_cam`` is ignored: the pose comes from the mount and the searched rotation).
    views : list of ViewObservation
        The other views.
    T_base_mount_ref : array_like (4, 4)
        Mount pose of the reference view (readings).
    T_base_mount : array_like (N, 4, 4)
        Mount poses of ``views``.
    t_mount_cam : array_like (3,)
        Camera centre in the mount frame (m; nominal).
    grid_y, grid_z : array_like
        Candidate ``theta_y0`` and ``theta_z0`` (rad); ``theta_y0`` is searched first with ``theta_z0 = 0``, then
        ``theta_z0`` with the best ``theta_y0`` (the thesis's order), ``theta_x0 = 0``.
    left, right : int
        Indices in ``views`` of the two views whose triangulations must agree in mean depth.
    depth_statistic : {"mean", "median"}
        ``"mean"``: the thesis's criterion, the difference of the mean depths of the common points. ``"median"``: the
        median of the per-point depth differences, which a few false matches that pass the gap filter cannot move
        (the thesis averaged over "six good keypoint matches"; with all matches, a handful of wrong ones with depth
        errors of decimetres shifted the mean by millimetres and theta_y0 by 1-2 deg in the x-y table scenario).
    theta_z0_during_y : float
        ``theta_z0`` (rad) assumed while ``theta_y0`` is searched (thesis: 0). A second pass with the first pass's
        ``theta_z0`` removes the coupling of the two searches (a wrong roll tilts the rotation axis of the views).
    """
    if depth_statistic not in ("mean", "median"):
        raise ValueError(f"depth_statistic: expected 'mean' or 'median', got {depth_statistic!r}")
    T_bm = _check_stack(T_base_mount, "T_base_mount")
    if len(T_bm) != len(views):
        raise ValueError(f"T_base_mount: {len(T_bm)} poses for {len(views)} views")
    matches = [match_features(reference.features, v.features, ratio, orientation_tol_deg).matches for v in views]

    def poses(ty, tz):
        X = homogeneous(mount_rotation(0.0, ty, tz), t_mount_cam)
        T_ref = T_base_mount_ref @ X
        return [invert(T_ref) @ T @ X for T in T_bm]

    def triang(k, T_ref_k):
        m = matches[k]
        tri = triangulate_midpoint([np.eye(4), T_ref_k], [reference.x_n[m.i1], views[k].x_n[m.i2]])
        return m.i1, tri

    def depth_gap(ty):
        P = poses(ty, theta_z0_during_y)
        il, tl = triang(left, P[left])
        ir, tr = triang(right, P[right])
        common, al, ar = np.intersect1d(il, ir, return_indices=True)
        ok = tl.valid[al] & tr.valid[ar] & (tl.gap[al] <= gap_max_m) & (tr.gap[ar] <= gap_max_m)
        if ok.sum() == 0:
            return np.inf
        if depth_statistic == "median":
            return abs(float(np.median(tl.ray_points[0][al][ok, 2] - tr.ray_points[0][ar][ok, 2])))
        return abs(float(np.mean(tl.ray_points[0][al][ok, 2]) - np.mean(tr.ray_points[0][ar][ok, 2])))

    def coinciding(ty, tz):
        P = poses(ty, tz)
        tris = [triang(k, P[k])[1] for k in range(len(views))]
        gaps = np.concatenate([t.gap[t.valid] for t in tris])
        return sum(int(np.sum(t.valid & (t.gap <= coincide_m))) for t in tris), float(np.median(gaps))

    gy = np.asarray(grid_y, dtype=float)
    gz = np.asarray(grid_z, dtype=float)
    cy = np.array([depth_gap(a) for a in gy])
    ty = float(gy[np.argmin(cy)])
    cz, med = np.array([coinciding(ty, a) for a in gz]).T
    tz = float(gz[np.lexsort((med, -cz))[0]])
    msg = (f"theta_y0 = {np.rad2deg(ty):.2f} deg ({depth_statistic}-depth gap {cy.min() * 1e3:.2f} mm), theta_z0 = "
           f"{np.rad2deg(tz):.2f} deg ({int(cz.max())} coinciding rays)")
    return MountSearchResult(0.0, ty, tz, (gy, cy), (gz, cz), msg)
