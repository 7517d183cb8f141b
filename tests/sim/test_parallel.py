"""Row bands in threads (bench.sim.parallel): the split, errors, and a forked child (a sweep worker) still works."""

import multiprocessing
import os

import numpy as np
import pytest

from bench.sim import parallel


def test_band_edges():
    e = parallel.band_edges(480 * 2, multiple=2)
    assert e[0] == 0 and e[-1] == 960 and len(e) == parallel.N_BANDS + 1 and np.all(e % 2 == 0)
    assert np.array_equal(parallel.band_edges(parallel.MIN_ROWS - 1), [0, parallel.MIN_ROWS - 1])  # small: one band


def test_map_bands_order_and_errors():
    edges = parallel.band_edges(100)
    assert parallel.map_bands(lambda r0, r1: (r0, r1), edges) == list(zip(edges[:-1], edges[1:], strict=True))

    def fail(r0, r1):
        if r0 > 0:
            raise ValueError("band failed")
        return r0

    with pytest.raises(ValueError, match="band failed"):
        parallel.map_bands(fail, edges)


def _child(queue):
    queue.put(parallel.map_bands(lambda r0, r1: r1 - r0, parallel.band_edges(100)))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork start method")
def test_a_forked_child_gets_its_own_pool():
    parallel.map_bands(lambda r0, r1: r0, parallel.band_edges(100))  # the parent's pool exists
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    proc = ctx.Process(target=_child, args=(queue,))
    proc.start()
    proc.join(timeout=60)
    if proc.is_alive():
        proc.kill()
        pytest.fail("the forked child hung on the parent's thread pool")
    assert queue.get(timeout=5) == [50, 50]
