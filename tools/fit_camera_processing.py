"""Fit a camera's processing (exposure, tone curve, sharpening) and its board's black to real chessboard photos.

    .venv/bin/python tools/fit_camera_processing.py --chain runs/replica-raw/renders [--data DIR] [--pattern 7x7]

The evidence is the photos' median edge profile across the square edges
(:func:`bench.camera.photo_stats.median_edge_profile`): a camera that sharpens dips below its black level beside
every edge (the real webcam photos: 37 DN, 1-3 px from the edge) and rises faster than a perfect pixel-integrating
camera could. A one-dimensional model of the chain reproduces that profile:

    linear = k (rho + (1 - rho) step)  ->  Gaussian optics sigma_o, pixel integration  ->  sRGB (IEC 61966-2-1)
    ->  unsharp mask  amount, sigma_u  ->  8 bits (clipped)

sampled at 16 sub-pixel phases of the edge (the unsharp mask is the chain's own,
:func:`bench.sim.imaging.unsharp_luma`) and aligned and summarised like the photos. ``sigma_o`` is the simulated
chain's own optics: it is fitted first to the median profile of renders made *without* the processing stages
(``--chain``: a ``camera_replica`` run with ``--set 'camera.imaging_off=[tone,sharpen,toner]'``, whose images are
linear; their black is the ideal scene's). Then ``k`` (the exposure of the board's white over the clip level),
``rho`` (the printed black over the white) and the unsharp mask's ``amount`` and ``sigma_u`` are fitted to the
photos (least squares over the profile, Nelder-Mead from several starts). The sharpening's coring threshold is not
in this model: it is the black squares' noise, matched with the replica (docs/realistic_imaging.md section 1.1).

The result is printed as the chain's parameters for this camera, ready for ``--set camera.imaging_params.<stage>.<key>``
(the defaults in :data:`bench.sim.imaging.REALISTIC` are the project webcam's): ``tone.exposure_scale`` = k over the
renders' own white level, ``toner.black_reflectance`` = the ideal scene's black (0.03) x rho over the renders' black
ratio, ``sharpen.amount`` and ``sharpen.sigma_px``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.camera.photo_stats import detect_views, median_edge_profile, parse_pattern, photo_paths  # noqa: E402
from bench.sim.imaging import srgb_oetf, unsharp_luma  # noqa: E402
from bench.sim.scenes.rig import BLACK_REFLECTANCE  # noqa: E402

PHASES = np.linspace(0, 1, 16, endpoint=False)
PIXELS = np.arange(-30, 31)


def model_profile(t, k, rho, sigma_o, amount, sigma_u, tone=True) -> np.ndarray:
    """The median over edge phases of the modelled edge profile (DN) at distances ``t`` (px), aligned like
    :func:`~bench.camera.photo_stats.median_edge_profile` (mid-level crossing, linear interpolation)."""
    sub = PIXELS[:, None] + (np.arange(5) + 0.5)[None] / 5 - 0.5  # 5 samples across each pixel
    out = []
    for phase in PHASES:
        lin = ndtr((sub - (phase - 0.5)) / max(sigma_o, 1e-3)).mean(1)
        x = k * (rho + (1 - rho) * lin)
        enc = 255 * (srgb_oetf(x) if tone else np.clip(x, 0, 1))
        if amount > 0:  # the chain's own stage, on a one-row grey image
            enc = unsharp_luma(np.repeat(enc[None, :, None], 3, axis=2), amount, sigma_u)[0, :, 0].astype(float)
        enc = np.clip(np.rint(enc), 0, 255)
        lo, hi = np.median(enc[:5]), np.median(enc[-5:])
        mid = (lo + hi) / 2
        j = np.nonzero((enc[:-1] < mid) & (enc[1:] >= mid))[0][0]
        x0 = PIXELS[j] + (mid - enc[j]) / (enc[j + 1] - enc[j])
        out.append(np.interp(t + x0, PIXELS, enc))
    return np.median(np.array(out), 0)


def _best(cost, starts):
    runs = [minimize(cost, x0, method="Nelder-Mead", options={"maxiter": 3000, "xatol": 1e-4, "fatol": 1e-3})
            for x0 in starts]
    return min(runs, key=lambda r: r.fun)


def profile_of(folder, pattern):
    try:
        files = photo_paths(folder)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    views = detect_views(files, pattern)
    if len(views) < 3:
        raise SystemExit(f"{folder}: the {pattern[0]}x{pattern[1]} board was found in {len(views)} images (need 3)")
    return median_edge_profile(views, pattern, step_px=1.0)


def fit(data, chain, pattern) -> dict:
    t, real, n_real = profile_of(data, pattern)
    _, raw, n_raw = profile_of(chain, pattern)
    dip = float(raw[0] - raw[: len(raw) // 2].min())
    if dip > 3.0:  # a linear, unsharpened edge rises monotonically from its black level
        raise SystemExit(f"--chain {chain}: the renders' edge dips {dip:.0f} DN below their black level, so they are "
                         "sharpened; make them with --set 'camera.imaging_off=[tone,sharpen,toner]'")
    rho_chain = (raw[0] / raw[-1])
    # the chain's optics: sigma_o and the white level of the linear renders (k), its black ratio as measured
    lin = _best(lambda q: np.sum((model_profile(t, q[1], rho_chain, q[0], 0.0, 1.0, tone=False) - raw) ** 2)
                if 0.05 < q[0] < 3 and 0.3 < q[1] < 2 else 1e12, ([0.7, 0.98], [0.4, 1.0]))
    sigma_o = float(lin.x[0])

    def cost(q):
        k, rho, a, su = q
        if not (0.3 < k < 20 and 0 < rho < 0.2 and 0 <= a < 5 and 0.3 < su < 5):
            return 1e12
        return np.sum((model_profile(t, k, rho, sigma_o, a, su) - real) ** 2)

    r = _best(cost, ([1.3, 0.02, 2.0, 1.5], [2.0, 0.01, 1.0, 2.0], [1.5, 0.02, 3.0, 1.0]))
    k, rho, a, su = (float(v) for v in r.x)
    plain = _best(lambda q: cost([q[0], q[1], 0.0, 1.0]), ([1.3, 0.02], [2.0, 0.01]))
    chain_white = float(lin.x[1])
    # the chain's parameters: its exposure scales the renders' own white (chain_white of the clip level), and the
    # printed black's reflectance scales the black ratio its scene gives (the renders' black is the ideal scene's)
    overrides = {"tone.exposure_scale": k / chain_white,
                 "toner.black_reflectance": BLACK_REFLECTANCE * rho / float(rho_chain),
                 "sharpen.amount": a, "sharpen.sigma_px": su}
    return {"profiles_real": n_real, "profiles_chain": n_raw, "chain_sigma_o_px": sigma_o,
            "chain_fit_rms_dn": float(np.sqrt(lin.fun / len(t))), "chain_white": chain_white,
            "chain_black_over_white": float(rho_chain), "exposure_scale": k, "black_over_white": rho,
            "sharpen_amount": a, "sharpen_sigma_px": su, "fit_rms_dn": float(np.sqrt(r.fun / len(t))),
            "without_sharpening_fit_rms_dn": float(np.sqrt(plain.fun / len(t))),
            "t_px": t.tolist(), "real_profile_dn": real.tolist(),
            "model_profile_dn": model_profile(t, k, rho, sigma_o, a, su).tolist(), "imaging_params": overrides}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT / "tests" / "data" / "real_webcam_chessboard"),
                    help="the real photos (default the project's webcam photos)")
    ap.add_argument("--chain", required=True, help="renders of the simulated camera without its processing stages")
    ap.add_argument("--pattern", default="7x7", help="inner corners per row x per column")
    ap.add_argument("--json", default=None, help="also write the fit to this JSON file")
    args = ap.parse_args(argv)
    try:
        pattern = parse_pattern(args.pattern)
    except ValueError as e:
        raise SystemExit(f"--pattern: {e}") from None
    for name in ("data", "chain"):
        if not Path(getattr(args, name)).is_dir():
            raise SystemExit(f"--{name}: {getattr(args, name)}: not a folder")
    out = fit(args.data, args.chain, pattern)
    for key, v in out.items():
        if not isinstance(v, (list, dict)):
            print(f"{key:32s} {v:.4g}" if isinstance(v, float) else f"{key:32s} {v}")
    print("profile (DN), every 1 px from the edge:\n  real  " + " ".join(f"{v:5.1f}" for v in out["real_profile_dn"])
          + "\n  model " + " ".join(f"{v:5.1f}" for v in out["model_profile_dn"]))
    print("the chain's parameters for this camera (the sharpening's coring is matched to the black squares' noise "
          "with the replica):\n  " + " ".join(f"--set camera.imaging_params.{key}={v:.4g}"
                                              for key, v in out["imaging_params"].items()))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
