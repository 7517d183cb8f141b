"""PNG figures for scenario reports (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.fileio import atomic_save_figure, headless_pyplot

plt = headless_pyplot()


def plot_orientation(table: dict, path) -> str:
    """Figures 36-39 of the thesis: position/rotation error of the end effector and of link 5 per configuration."""
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    panels = [("ee_pos_err_mm", "Fig. 36 - end-effector position error (O6)", "mm"),
              ("ee_rot_err_deg", "Fig. 37 - end-effector rotation error", "deg"),
              ("link5_pos_err_mm", "Fig. 38 - link 5 position error", "mm"),
              ("link5_rot_err_deg", "Fig. 39 - link 5 rotation error", "deg")]
    for ax, (key, title, unit) in zip(axes.ravel(), panels, strict=True):
        for a in "xyz":
            v = np.asarray(table[f"{key}_{a}"])
            ax.plot(np.arange(1, len(v) + 1), v, ".-", ms=3, lw=0.7, label=f"{a}")
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    for ax in axes[1]:
        ax.set_xlabel("configuration")
    fig.suptitle("Calibrated (reduced errors) vs true arm, Eq. 189 - link 5's deviation is a constant bias")
    fig.tight_layout()
    atomic_save_figure(fig, path, dpi=110)
    return Path(path).name


def plot_monte_carlo(table: dict, path) -> str:
    """Predicted (covariance) vs Monte-Carlo standard deviation of every identified error."""
    fig, ax = plt.subplots(figsize=(11, 4))
    x = np.arange(len(table["name"]))
    ax.bar(x - 0.2, table["predicted_std"], 0.4, label="predicted (covariance)")
    ax.bar(x + 0.2, table["monte_carlo_std"], 0.4, label="Monte Carlo")
    ax.set_yscale("log")
    ax.set_xticks(x, table["name"], rotation=90, fontsize=8)
    ax.set(ylabel="std (mm or rad)", title="Identified errors: predicted vs observed spread")
    ax.legend()
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    atomic_save_figure(fig, path, dpi=110)
    return Path(path).name
