"""The planning memo (bench.scenario.plan_memo): a hit only for arguments equal to the bit, and a copy each time."""

from pathlib import Path

import numpy as np
import pytest

from bench.robot.model import load_robot
from bench.scenario.plan_memo import memoized
from bench.sim.views import look_at_configuration

ROOT = Path(__file__).resolve().parents[2]


def test_a_hit_needs_every_argument_equal_to_the_bit_and_returns_a_copy():
    calls = []

    @memoized
    def f(robot, q, rows, flag=False):
        calls.append(1)
        return {"q": np.asarray(q, float) * 2, "rows": list(rows), "flag": flag}

    robot = load_robot(ROOT / "models" / "ta40.yaml")
    q = np.array([0.1, 0.2, 0.3])
    first = f(robot, q, [("a", np.ones(2))])
    first["q"][0] = 99.0  # the caller's copy: the memo keeps its own
    again = f(robot, q.copy(), [("a", np.ones(2))])
    assert len(calls) == 1 and f.memo_info() == (1, 1)
    assert again["q"][0] == 0.2 and again["q"] is not first["q"]
    f(robot, np.nextafter(q, 1.0), [("a", np.ones(2))])  # one ulp apart: planned again
    f(robot, q, [("a", np.ones(2))], flag=True)
    f(robot, q, [("b", np.ones(2))])
    f(robot.with_ee_point([0.0, 0.0, 0.1]), q, [("a", np.ones(2))])  # another robot
    f(robot, q.astype(np.float32), [("a", np.ones(2))])  # another dtype
    assert len(calls) == 6
    f.memo_clear()
    assert f.memo_info() == (0, 0)
    with pytest.raises(TypeError, match="cannot key"):
        f(robot, q, [object()])


def test_a_memoised_view_plan_is_the_plan():
    """look_at_configuration through the memo: the same solution, bit for bit, planned or remembered."""
    robot = load_robot(ROOT / "models" / "ta40.yaml")
    plan = memoized(look_at_configuration)
    mount = np.eye(4)
    mount[:3, 3] = [0.05, 0.0, 0.1]
    args = (robot, np.array([0.9, 0.1, 0.3]), np.array([1.6, 0.1, 0.3]), mount)
    direct = look_at_configuration(*args, n_starts=4)
    a, b = plan(*args, n_starts=4), plan(*args, n_starts=4)
    assert plan.memo_info() == (1, 1)
    for sol in (a, b):
        assert sol.success == direct.success and sol.message == direct.message
        assert np.array_equal(sol.q, direct.q)
