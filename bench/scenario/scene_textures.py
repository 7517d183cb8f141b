"""Scenario keys that put any image on a scene's faces: ``site.textures`` (in_situ: the manifold panel) and
``sim.textures`` (xy_table: the reference object).

The value is a mapping from a face name (the panel's ``features["faces"]``: ``backplate``, label and gauge faces) to
an image file, relative to the scenario file or absolute, e.g. ``--set
site.textures.backplate=data/textures/natural_gravel.png``. The image is resized to the face's texture (see
:func:`bench.sim.scenes.panel.manifold_panel`). An unknown face, a missing or unreadable file, or a value that is not
a file name is a one-line :class:`~bench.errors.ConfigError` naming the key (``site.textures.<face>``). Freely
licensed photographs are vendored under ``scenarios/data/textures/`` (PROVENANCE.md there).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import cv2
import numpy as np

from bench.errors import ConfigError


def texture_paths(cfg, key: str) -> dict:
    """``{face: Path}`` of the mapping at the dotted ``key`` (each file checked readable now, before any render)."""
    sec, k = key.split(".")
    value = cfg[sec][k]
    src = cfg["_file"]
    if not isinstance(value, dict):
        raise ConfigError(src, key, f"expected a mapping face -> image file, got {value!r}")
    out = {}
    for face, file in value.items():
        name = f"{key}.{face}"
        if not isinstance(face, str) or not isinstance(file, str) or not file:
            raise ConfigError(src, name, f"expected an image file name, got {file!r}")
        p = Path(file).expanduser()
        if not p.is_absolute():
            p = Path(src).parent / p
        if not p.is_file():
            raise ConfigError(src, name, f"image file not found: {p}")
        if cv2.imdecode(np.frombuffer(p.read_bytes(), np.uint8), cv2.IMREAD_COLOR) is None:
            raise ConfigError(src, name, f"not a readable image file: {p}")
        out[face] = p
    return out


@contextlib.contextmanager
def naming_the_key(cfg, key: str):
    """Re-raise the scene builder's unknown-face error as one naming the scenario key (``key.<face>``)."""
    try:
        yield
    except ConfigError as exc:
        if exc.source == "texture_overrides":  # manifold_panel: ConfigError("texture_overrides", face, problem)
            raise ConfigError(cfg["_file"], f"{key}.{exc.field}", exc.problem) from None
        raise
