"""An exact in-process memo for the arm's view and task planning (pure, deterministic, and slow).

Planning a campaign (:func:`bench.sim.views.look_at_configuration` per view, :func:`bench.robot.ik.compensated_ik`
for the taught valve) takes tens of seconds, and runs that differ only in what they render or how they localise -
the imaging, the water, the panel's texture, a budget's switched-off source, a smoke test's second preset - plan the
same views from the same inputs. Both functions are deterministic (their random starts come from a fixed seed), so a
result can be reused whenever every input is equal to the bit: the key is the exact bytes of every array argument,
the robot's every field, every float's ``hex`` and every other scalar's ``repr``. A hit returns a deep copy; nothing
is approximated.
"""

from __future__ import annotations

import copy
import dataclasses
import functools

import numpy as np

#: Entries kept per memoised function; beyond it the memo starts afresh (a campaign plans some hundreds of views).
MAX_ENTRIES = 4096


def _key(x):
    """A hashable key equal for two arguments exactly when they are equal to the bit."""
    if isinstance(x, np.ndarray):
        return ("ndarray", x.dtype.str, x.shape, x.tobytes())
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return (type(x).__qualname__,) + tuple(_key(getattr(x, f.name)) for f in dataclasses.fields(x))
    if isinstance(x, (list, tuple)):
        return (type(x).__name__,) + tuple(_key(v) for v in x)
    if isinstance(x, dict):
        return ("dict",) + tuple((k, _key(v)) for k, v in sorted(x.items()))
    if isinstance(x, (float, np.floating)):
        return ("float", float(x).hex())
    if x is None or isinstance(x, (bool, int, str, np.integer, np.bool_)):
        return (type(x).__name__, repr(x))
    raise TypeError(f"plan_memo: cannot key an argument of type {type(x).__name__}")


def memoized(fn):
    """Memoise ``fn`` (a pure function) on the exact values of its arguments; ``fn.memo_info()`` gives
    ``(hits, misses)`` and ``fn.memo_clear()`` empties it."""
    memo, stats = {}, [0, 0]

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        key = (_key(args), _key(kwargs))
        if key in memo:
            stats[0] += 1
            return copy.deepcopy(memo[key])
        stats[1] += 1
        out = fn(*args, **kwargs)
        if len(memo) >= MAX_ENTRIES:
            memo.clear()
        memo[key] = copy.deepcopy(out)
        return out

    def memo_clear():
        memo.clear()
        stats[:] = [0, 0]

    wrapper.memo_info = lambda: tuple(stats)
    wrapper.memo_clear = memo_clear
    return wrapper
