"""Keypoints aligned to the reference view's by their image patches (not the thesis's; ``pipeline.keypoints``).

SIFT places a keypoint at an extremum of a difference of Gaussians, found in each image on its own. Seen from
another direction the same texture is foreshortened, and the extremum moves on the surface by a part of the blob's
size: the keypoints of one map point in two views are not images of the same surface point. That error is not
noise - it is the same for every view from the same direction - and it is most of the in-situ base error under
realistic imaging (docs/integrity.md: with the arm, camera and encoders handed over as the truth the error stays;
with exact projections it falls four-fold).

This stage moves every keypoint of a view that is matched to a reference keypoint so that the view's image around it
matches the reference's patch around the reference keypoint, warped by the local affine map between the two images
(:func:`local_affines`: fitted to the view's neighbouring matches, so no camera model, kinematics or scene is
assumed). The reference keypoint is the anchor: every view's keypoint then images the surface point the reference
keypoint images, to the alignment's precision. The alignment (:func:`align`) is Lucas-Kanade, forward additive, on
the translation with a gain and an offset of the intensities:

    min over (delta, a, b) of  sum_d w(d) [I_view(c + A d + delta) - a I_ref(u_ref + d) - b]^2,

``d`` on the pixel grid of a ``(2h + 1)^2`` patch, ``w`` a Gaussian window, images sampled bicubically. A keypoint
whose alignment does not converge, moves by more than :data:`MAX_SHIFT_PX`, correlates below :data:`MIN_NCC`, is
less certain than :data:`MAX_SIGMA_PX` (an edge or a repeated texture: the patch slides along it) or leaves the
image keeps SIFT's position (a wrong match does not correlate: it is left to RANSAC and the gates).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.spatial import cKDTree

from bench.vision.features import _grey

#: the patch's half size (px, in the reference image)
HALF_PX = 8
#: the Gaussian window's standard deviation, as a fraction of the half size
WINDOW_FRACTION = 0.6
#: neighbouring matches that fit each keypoint's local affine map
NEIGHBOURS = 12
#: a neighbour farther than this from the local affine fit (px) is left out of it (wrong matches)
AFFINE_GATE_PX = 3.0
#: Gauss-Newton iterations, and the step (px) below which the alignment has converged
ITERATIONS = 30
CONVERGED_PX = 1e-3
#: accepted alignments: normalised cross-correlation of the aligned patches, the aligned position's largest standard
#: deviation (px) and the largest move from SIFT's keypoint. Measured against the truth on a 0.5 m envelope run
#: (docs/integrity.md): 1.6 % of the matches were keypoints SIFT placed within 0.25 px that the alignment moved beyond
#: 0.5 px with the correlation alone (>= 0.8), 0.2 % with these; such moves correlate at 0.95 (median) against 0.99
#: and have a standard deviation of 0.12 px (median) against 0.035 px - an edge or a repeated texture the patch
#: slides along.
MIN_NCC = 0.9
MAX_SIGMA_PX = 0.08
MAX_SHIFT_PX = 2.0


@dataclass(frozen=True)
class Alignment:
    """Outcome of :func:`align` for N keypoints: ``uv`` (N, 2) the aligned positions (SIFT's where not ``ok``),
    ``ok`` (N,) accepted, ``ncc`` (N,) the aligned patches' correlation, ``shift_px`` (N,) the move from the start,
    ``iterations`` (N,) used, ``sigma_px`` (N,) the aligned position's largest standard deviation (px; from the
    final residuals and the Gauss-Newton matrix, gain and offset marginalised)."""

    uv: np.ndarray
    ok: np.ndarray
    ncc: np.ndarray
    shift_px: np.ndarray
    iterations: np.ndarray
    sigma_px: np.ndarray


def grey(image) -> np.ndarray:
    """``float32 (H, W)`` intensities of an RGB(A) or grey image as :func:`~bench.vision.features.detect_sift` sees
    it (the same conversion)."""
    return _grey(image, channel_order="rgb").astype(np.float32)


def local_affines(uv_ref, uv_view, neighbours: int = NEIGHBOURS, gate_px: float = AFFINE_GATE_PX) -> tuple:
    """Per match, the affine map's linear part ``A`` (2, 2) from the reference image to the view's around it.

    Fitted by least squares to the ``neighbours`` matches nearest in the reference image (the match itself
    included), twice more without those farther from the last fit than ``gate_px`` or 2.5x the median distance of
    those it was fitted to, whichever is larger (a wrong match among them pulls the first fit by a fraction of its
    own error).

    Parameters
    ----------
    uv_ref, uv_view : array_like (N, 2)
        Matched keypoints (px) in the reference image and the view.

    Returns
    -------
    A : ndarray (N, 2, 2)
        ``uv_view - c_view ~ A (uv_ref - c_ref)`` near each match.
    ok : ndarray (N,) bool
        False where fewer than 4 matches are left or the neighbours are collinear (no affine map).
    """
    u, v = np.asarray(uv_ref, float).reshape(-1, 2), np.asarray(uv_view, float).reshape(-1, 2)
    n = len(u)
    A, ok = np.tile(np.eye(2), (n, 1, 1)), np.zeros(n, bool)
    if n < 4:
        return A, ok
    k = min(neighbours, n)
    _, nb = cKDTree(u).query(u, k=k)
    nb = nb.reshape(n, k)
    keep = np.ones((n, k), bool)
    for _ in range(3):
        Uc = u[nb] - u[:, None]                                           # (n, k, 2) about the match
        M = np.concatenate([Uc, np.ones((n, k, 1))], axis=2) * keep[..., None]
        Y = v[nb] * keep[..., None]
        MtM = np.einsum("nki,nkj->nij", M, M)
        good = (keep.sum(axis=1) >= 4) & (np.linalg.cond(MtM) < 1e8)
        P = np.zeros((n, 3, 2))
        P[good] = np.linalg.solve(MtM[good], np.einsum("nki,nkj->nij", M[good], Y[good]))
        r = np.linalg.norm(np.concatenate([Uc, np.ones((n, k, 1))], axis=2) @ P - v[nb], axis=2)
        r_kept = np.where(keep, r, np.nan)
        r_kept[~keep.any(axis=1)] = 0.0  # nothing kept: the gate alone
        keep = r <= np.maximum(gate_px, 2.5 * np.nanmedian(r_kept, axis=1))[:, None]
    A[good], ok = np.transpose(P[good, :2], (0, 2, 1)), good
    return A, ok


def _sample(img, xy) -> np.ndarray:
    """Bicubic samples of ``img`` at ``xy`` (..., 2) (x = column, y = row, pixel centres at integers)."""
    shape = xy.shape[:-1]
    m = xy.reshape(-1, shape[-1], 2).astype(np.float32)   # one row per patch (remap wants < 32767 of each)
    out = [cv2.remap(img, c[..., 0], c[..., 1], interpolation=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
           for c in np.array_split(m, max(1, -(-len(m) // 30000)))]
    return np.concatenate(out).reshape(shape)


def align(img_ref, img_view, uv_ref, uv_view, A, half: int = HALF_PX, iterations: int = ITERATIONS) -> Alignment:
    """Lucas-Kanade alignment of the view's keypoints to the reference's patches (the module docstring's problem).

    Parameters
    ----------
    img_ref, img_view : ndarray (H, W) float32
        Grey images (:func:`grey`).
    uv_ref, uv_view : array_like (N, 2)
        The reference keypoints (the anchors, not moved) and the view's keypoints to move (the start).
    A : array_like (N, 2, 2)
        The local affine maps (:func:`local_affines`).
    """
    u = np.asarray(uv_ref, float).reshape(-1, 2)
    c0 = np.asarray(uv_view, float).reshape(-1, 2)
    A = np.asarray(A, float).reshape(-1, 2, 2)
    n = len(u)
    if n == 0:
        return Alignment(np.empty((0, 2)), np.zeros(0, bool), np.empty(0), np.empty(0), np.zeros(0, int), np.empty(0))
    g = np.arange(-half, half + 1, dtype=float)
    d = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)               # (P, 2) offsets, x then y
    w = np.exp(-0.5 * np.sum(d ** 2, axis=1) / (WINDOW_FRACTION * half) ** 2)
    T = _sample(img_ref, u[:, None] + d)                                    # (N, P) the reference patches
    gx = cv2.Sobel(img_view, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)       # central differences
    gy = cv2.Sobel(img_view, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
    Ad = np.einsum("nij,pj->npi", A, d)                                   # (N, P, 2) the warped grid about c
    delta = np.zeros((n, 2))
    live = np.ones(n, bool)
    used = np.zeros(n, int)
    for it in range(iterations):
        if not live.any():
            break
        xy = c0[live, None] + Ad[live] + delta[live, None]
        W = _sample(img_view, xy)
        G = np.stack([_sample(gx, xy), _sample(gy, xy)], axis=-1)           # (m, P, 2)
        J = np.concatenate([G, -T[live, :, None], -np.ones_like(W)[..., None]], axis=2)   # (m, P, 4)
        Jw = J * w[None, :, None]
        H = np.einsum("mpi,mpj->mij", Jw, J) + 1e-9 * np.eye(4)
        # W + G step - a T - b = 0 in least squares: the gain and offset solved afresh each time (they are linear)
        rhs = -np.einsum("mpi,mp->mi", Jw, W)
        step = np.linalg.solve(H, rhs[..., None])[:, :2, 0]
        idx = np.flatnonzero(live)
        delta[idx] += step
        used[idx] = it + 1
        live[idx[np.linalg.norm(step, axis=1) < CONVERGED_PX]] = False
    converged = ~live
    xy = c0[:, None] + Ad + delta[:, None]
    inside = _inside(xy, img_view.shape) & _inside(u[:, None] + d, img_ref.shape)
    W = _sample(img_view, xy)
    ncc = _weighted_ncc(W, T, w)
    sigma = _position_sigma(W, T, _sample(gx, xy), _sample(gy, xy), w)
    shift = np.linalg.norm(delta, axis=1)
    ok = (converged & inside & (ncc >= MIN_NCC) & (sigma <= MAX_SIGMA_PX) & (shift <= MAX_SHIFT_PX)
          & np.all(np.isfinite(delta), axis=1))
    return Alignment(np.where(ok[:, None], c0 + delta, c0), ok, ncc, shift, used, sigma)


def _position_sigma(W, T, Gx, Gy, w) -> np.ndarray:
    """The largest standard deviation (N,) (px) of the aligned position: the weighted residual variance of the
    intensity model ``W ~ a T + b`` times the translation block of the inverse Gauss-Newton matrix."""
    J = np.stack([Gx, Gy, -T, -np.ones_like(W)], axis=2)
    Jw = J * w[None, :, None]
    H = np.einsum("npi,npj->nij", Jw, J) + 1e-9 * np.eye(4)
    ab = np.linalg.solve(H[:, 2:, 2:], -np.einsum("npi,np->ni", Jw[..., 2:], W)[..., None])[..., 0]
    r = W - ab[:, :1] * T - ab[:, 1:]
    var = (w * r ** 2).sum(axis=1) / max(w.sum() - 4.0, 1.0)
    C = np.linalg.inv(H)[:, :2, :2] * var[:, None, None]
    return np.sqrt(np.clip(np.linalg.eigvalsh(C)[:, -1], 0.0, None))


def _inside(xy, shape) -> np.ndarray:
    """(N,) every sample of each patch ``xy`` (N, P, 2) at least a pixel inside an image of ``shape`` (H, W)."""
    h, w = shape[:2]
    return np.all((xy[..., 0] >= 1) & (xy[..., 0] <= w - 2) & (xy[..., 1] >= 1) & (xy[..., 1] <= h - 2), axis=1)


def _weighted_ncc(a, b, w) -> np.ndarray:
    """Normalised cross-correlation (N,) of patches ``a``, ``b`` (N, P) under the window ``w`` (P,)."""
    w = w / w.sum()
    da = a - (a * w).sum(axis=1, keepdims=True)
    db = b - (b * w).sum(axis=1, keepdims=True)
    den = np.sqrt((w * da ** 2).sum(axis=1) * (w * db ** 2).sum(axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, (w * da * db).sum(axis=1) / den, 0.0)


def unique_matches(i_view, distance=None) -> np.ndarray:
    """Indices (in their order) of the matches :func:`align_view` keeps: per view keypoint ``i_view`` the match of the
    smallest descriptor ``distance`` (the first one without it)."""
    i_view = np.asarray(i_view, int)
    order = np.argsort(distance, kind="stable") if distance is not None else np.arange(len(i_view))
    return np.sort(order[np.unique(i_view[order], return_index=True)[1]])


def align_view(img_ref, img_view, uv_ref, uv_view, i_ref, i_view, distance=None) -> tuple:
    """The view's keypoints ``uv_view`` (N, 2) with those matched to reference keypoints moved onto them.

    ``i_ref``, ``i_view`` the matches (indices into ``uv_ref`` and ``uv_view``); a view keypoint matched twice keeps
    the match of the smaller descriptor ``distance`` (the first one without it). Returns ``(uv, alignment)``: the
    keypoints (a copy) and the :class:`Alignment` of the matches kept (in their order).
    """
    keep = unique_matches(i_view, distance)
    i_ref, i_view = np.asarray(i_ref, int)[keep], np.asarray(i_view, int)[keep]
    uv = np.array(uv_view, float, copy=True).reshape(-1, 2)
    A, fit = local_affines(np.asarray(uv_ref, float)[i_ref], uv[i_view])
    al = align(img_ref, img_view, np.asarray(uv_ref, float)[i_ref], uv[i_view], A)
    ok = al.ok & fit
    al = Alignment(np.where(ok[:, None], al.uv, uv[i_view]), ok, al.ncc, al.shift_px, al.iterations, al.sigma_px)
    uv[i_view[ok]] = al.uv[ok]
    return uv, al


def align_to_reference(img_ref, f_ref, views: dict, match) -> tuple:
    """Every view's keypoints matched to the reference's moved onto the reference's patches (:func:`align_view`).

    Parameters
    ----------
    img_ref : ndarray (H, W) float32
        The reference image (:func:`grey`); ``f_ref`` its :class:`~bench.vision.features.Features`.
    views : dict {name: (image, Features)}
        The other views: grey image and keypoints.
    match : callable
        ``match(f_ref, f_view) -> Matches`` (the caller's matching: ratio test, orientation filter).

    Returns
    -------
    features : dict {name: Features}
        Each view's keypoints, aligned where accepted (the same keypoints, in the same order; a view with fewer
        than 4 matches as it was).
    matched : int
        View keypoints matched to a reference keypoint.
    shift_px : ndarray (n,)
        The aligned keypoints' moves (px).
    """
    out, matched, shifts = {}, 0, []
    for name, (img, f) in views.items():
        m = match(f_ref, f)
        if len(m) < 4:
            out[name] = f
            continue
        uv, al = align_view(img_ref, img, f_ref.uv, f.uv, m.i1, m.i2, m.distance)
        matched += len(al.ok)
        shifts.append(al.shift_px[al.ok])
        out[name] = replace(f, uv=uv)
    return out, matched, np.concatenate(shifts) if shifts else np.empty(0)

