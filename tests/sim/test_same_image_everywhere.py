"""A seed gives the same image on every machine (issue 12): the scenes' texture generators and the imaging chain's
OpenCV stages held to the digests of the versions the published figures were rendered with.

OpenCV 5.1 draws ``cv2.putText``'s fonts differently from 5.0 (``getTextSize("V-12", FONT_HERSHEY_DUPLEX, 2, 3)``
145 px wide against 146): every panel texture with a label changed, and with it every in-situ view of a seed, while
the rigs' views (no text) stayed byte-identical (docs/realistic_imaging.md, "A seed, the same image"). pyproject.toml
asks for OpenCV 5.1 or newer; a newer OpenCV, numpy or scipy that changes these pixels fails here, naming the
version, before a sweep silently measures other images.
"""

import functools
import hashlib

import cv2
import numpy as np
import pytest

from bench.sim import imaging
from bench.sim.scenes import textures as tx

#: sha256 (first 16 hex digits) of each image below, recorded with OpenCV 5.1.0, numpy 2.4.6
DIGESTS = {
    "label_plate": "bfd23de4b52ff3d5",
    "dial_face": "c7610ed873713e34",
    "stencil_on_metal": "d66b449509c24335",
    "fractal_noise": "6ad1adf3ddf003b3",
    "demosaic_edge_aware": "ca41bbce9f4b9f79",
    "unsharp_luma": "ad4b29caf1897d8c",
    "frame_grab_cubic_spline": "8ffc6d6e34e66e00",  # and scipy 1.17.1
}


@functools.cache
def _images() -> dict:
    rng = np.random.default_rng(20261202)
    metal = tx.painted_metal(np.random.default_rng(3), (128, 192))
    tx.stencil_text(metal, "PLEM-07", (10, 80), 24, tx.BLACK)
    rgb = (rng.random((64, 96, 3)) * 255).astype(np.uint8)
    return {
        "label_plate": tx.label_plate(np.random.default_rng(1), ["V-112", "OPEN"], (64, 160)),
        "dial_face": tx.dial_face(np.random.default_rng(2), 160),
        "stencil_on_metal": metal,
        "fractal_noise": tx.fractal_noise(np.random.default_rng(4), (96, 128)),
        "demosaic_edge_aware": imaging.demosaic(imaging.mosaic(rgb), "edge_aware"),
        "unsharp_luma": imaging.unsharp_luma(rgb.astype(np.float32) / 255, 0.6, 1.2),
        "frame_grab_cubic_spline": imaging.frame_grab(rgb, (48, 32)),
    }


def _digest(a) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha256(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes()).hexdigest()[:16]


@pytest.mark.parametrize("name", sorted(DIGESTS))
def test_a_seed_draws_the_published_pixels(name):
    got = _digest(_images()[name])
    assert got == DIGESTS[name], (
        f"{name}: digest {got}, recorded {DIGESTS[name]} with OpenCV 5.1.0 / numpy 2.4.6; installed OpenCV "
        f"{cv2.__version__}, numpy {np.__version__}: a seed's renders are not those the published figures were made "
        "with (re-record DIGESTS and re-run make reproduce, or install the recorded versions)")
