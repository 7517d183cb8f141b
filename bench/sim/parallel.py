"""Row bands of an image processed in parallel threads (the simulator's per-pixel stages).

NumPy's element-wise kernels and OpenCV release the GIL on large arrays, so the per-pixel work of the optics and
sensor stages (the flat-port depth fixed point, the lamp, attenuation, noise) runs on two cores when the image is
split into horizontal bands handled by two threads. Results never depend on the number of threads: the split into
:data:`N_BANDS` bands is fixed (the sensor draws each band's noise from its own child generator, so an image is
reproducible from its seed on any machine), only how many bands run at the same time follows the machine.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

#: bands an image is split into (fixed: the sensor noise of a seed must not depend on the machine)
N_BANDS = 2
#: images with fewer rows are not split
MIN_ROWS = 64

_POOL: ThreadPoolExecutor | None = None


def _forget_pool() -> None:
    """In a forked child the pool's threads do not exist: start a new pool there (a sweep forks its workers)."""
    global _POOL
    _POOL = None


os.register_at_fork(after_in_child=_forget_pool)


def _pool() -> ThreadPoolExecutor | None:
    global _POOL
    workers = min(N_BANDS, os.cpu_count() or 1)
    if workers < 2:
        return None
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="bench-sim-band")
    return _POOL


def band_edges(n_rows: int, multiple: int = 1) -> np.ndarray:
    """Row edges ``(n + 1,)`` of the bands of an image with ``n_rows`` rows; every edge is a multiple of ``multiple``
    (e.g. the supersampling factor, so that a band holds whole output pixels). One band for small images."""
    n = N_BANDS if n_rows >= MIN_ROWS else 1
    units = n_rows // multiple
    edges = np.round(np.linspace(0, units, n + 1)).astype(int) * multiple
    edges[-1] = n_rows
    return edges


def map_bands(fn, edges) -> list:
    """``[fn(r0, r1) for each band]``, the bands run in parallel threads; exceptions propagate.

    The calling thread runs the first band itself, so ``fn`` must not call :func:`map_bands` (a pool thread waiting
    for the pool could wait forever).
    """
    bands = list(zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True))
    pool = _pool()
    if pool is None or len(bands) == 1:
        return [fn(r0, r1) for r0, r1 in bands]
    futures = [pool.submit(fn, r0, r1) for r0, r1 in bands[1:]]
    first = fn(*bands[0])  # the calling thread does the first band
    return [first] + [f.result() for f in futures]
