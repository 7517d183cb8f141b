"""Plots of camera calibrations (matplotlib, Agg backend): the residual-vector figure of the thesis (Figures 44/53)."""

from __future__ import annotations

import numpy as np

from bench.fileio import atomic_save_figure, headless_pyplot

plt = headless_pyplot()


def plot_residual_vectors(path, image_points, residuals_px, image=None, image_size=None, scale: float = 50.0,
                          title: str | None = None, rms_px: float | None = None):
    """Draw the reprojection residuals ``p_e - p_p`` magnified ``scale`` times at the detected points (Fig. 44/53).

    Parameters
    ----------
    path : str or Path
        Output PNG.
    image_points : array (N, 2) or list of arrays
        Detected pixels ``p_e`` (px); a list (several views) is drawn on one canvas.
    residuals_px : array (N, 2) or list of arrays
        Detected minus predicted pixels, same layout (``CalibrationResult.residuals_px``).
    image : ndarray (H, W) or (H, W, 3), optional
        The calibration image drawn underneath (BGR as read by OpenCV, or grey).
    image_size : (width, height), optional
        Canvas size when no image is given.
    scale : float
        Magnification of the vectors (the thesis uses 50).
    title : str, optional
    rms_px : float, optional
        Printed in the title (Eq. 196).

    Returns
    -------
    Path
    """
    pts = np.vstack(image_points) if isinstance(image_points, (list, tuple)) else np.asarray(image_points, float)
    res = np.vstack(residuals_px) if isinstance(residuals_px, (list, tuple)) else np.asarray(residuals_px, float)
    if pts.shape != res.shape or pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"residuals_px: shape {res.shape} does not match image_points {pts.shape} (expected (N, 2))")
    if image is not None:
        h, w = image.shape[:2]
    elif image_size is not None:
        w, h = image_size
    else:
        raise ValueError("image_size: give the image or its (width, height)")
    fig, ax = plt.subplots(figsize=(8, 8 * h / w), dpi=100)
    if image is not None:
        shown = image[..., ::-1] if image.ndim == 3 else image
        ax.imshow(shown, cmap="gray" if image.ndim == 2 else None)
    ax.plot(pts[:, 0], pts[:, 1], "r.", ms=3, label="detected $p_e$")
    ax.quiver(pts[:, 0], pts[:, 1], scale * res[:, 0], scale * res[:, 1], angles="xy", scale_units="xy", scale=1.0,
              color="yellow" if image is not None else "blue", width=0.002, label=f"$p_e - p_p$ x{scale:g}")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title((title or "reprojection residuals") + ("" if rms_px is None else f" (chi = {rms_px:.3f} px)"))
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    return atomic_save_figure(fig, path)
