import numpy as np
import pytest

from bench.robot.identifiability import closed_form_reduction, numeric_identifiability
from bench.robot.jacobian import identification_jacobian
from bench.robot.model import random_errors, robot_from_dict

THESIS_KEPT = ["x0", "y0", "s0", "p0", "x1", "y1", "s1", "p1", "x2", "y2", "s2", "p2", "x3", "y3", "s3", "p3",
               "x4", "y4", "s4", "p4", "x5", "p5", "x6", "y6", "z6"]


def test_ta40_closed_form_gives_the_thesis_25(ta40):
    red = closed_form_reduction(ta40)
    assert red.names == THESIS_KEPT  # section 4.4: 25 errors
    # Eq. 167 with d6 = 0.36 m
    assert red.merged["s5"] == pytest.approx({"x5": 0.36})
    assert red.merged["y5"]["p5"] == pytest.approx(-1 / 0.36)


def test_reduction_preserves_measurements(ta40, rng):
    # Eq. 20: J_e eps == G_e eps_dot, for any eps and pose
    red = closed_form_reduction(ta40)
    q = ta40.random_configurations(rng, 30)
    J = identification_jacobian(ta40, q)
    for _ in range(5):
        eps = random_errors(rng)
        assert np.abs(J @ eps - J[..., red.kept] @ red.reduce(eps)).max() < 1e-15


@pytest.mark.parametrize("p_ee, rank", [([0, 0, 0], 25), ([0.05, 0.0, 0.1], 27), ([0.0, 0.03, 0.0], 27),
                                        ([0.0, 0.0, 0.2], 25)])
def test_closed_form_agrees_with_numeric(ta40, rng, p_ee, rank):
    robot = ta40.with_ee_point(p_ee)
    cf = closed_form_reduction(robot)
    num = numeric_identifiability(robot, rng, preferred=cf.kept)
    assert num.rank == len(cf.kept) == rank
    assert np.array_equal(num.kept, cf.kept)
    assert np.abs(num.M - cf.M).max() < 1e-9


def test_full_pose_measurement(ta40, rng):
    cf = closed_form_reduction(ta40, rows="pose")
    num = numeric_identifiability(ta40, rng, rows="pose", preferred=cf.kept)
    assert num.rank == len(cf.kept) == 30  # 6n: Eq. 16-17 only
    assert np.abs(num.M - cf.M).max() < 1e-9


def test_numeric_analysis_for_another_robot(rng):
    # a planar-ish 3R arm with a point off the last axis: numeric analysis works for any DH robot
    j = [{"a_mm": 300, "d_mm": 0, "alpha_deg": 0, "min_deg": -170, "max_deg": 170},
         {"a_mm": 250, "d_mm": 0, "alpha_deg": 90, "min_deg": -170, "max_deg": 170},
         {"a_mm": 0, "d_mm": 100, "alpha_deg": 0, "min_deg": -170, "max_deg": 170}]
    robot = robot_from_dict({"name": "3R", "joints": j, "ee_point_mm": [40, 0, 0]})
    num = numeric_identifiability(robot, rng)
    cf = closed_form_reduction(robot)
    assert num.rank == len(cf.kept) == 4 * 6 - 6 - 3
    J = identification_jacobian(robot, robot.random_configurations(rng, 20))
    eps = random_errors(rng, n_frames=4)
    assert np.abs(J @ eps - J[..., num.kept] @ num.reduce(eps)).max() < 1e-12


def test_point_at_frame_origin_is_refused_by_closed_form(ta40, rng):
    robot = ta40.with_ee_point([0, 0, -0.36])  # O5: the recursive case of Eq. 23-26
    with pytest.raises(ValueError, match="numeric_identifiability"):
        closed_form_reduction(robot)
    assert numeric_identifiability(robot, rng).rank == 21


def test_numeric_rank_refuses_too_few_poses(ta40):
    """2 poses used to report 'rank 6' for the TA-40's 25 identifiable errors: the rank counted the rows."""
    for n in (2, 8):
        with pytest.raises(ValueError, match=f"n_poses: {n} poses give {3 * n} rows .* at least 15 poses"):
            numeric_identifiability(ta40, np.random.default_rng(0), n)
    assert numeric_identifiability(ta40, np.random.default_rng(0), 9).rank == 25  # 27 rows suffice
    with pytest.raises(ValueError, match="positive integer"):
        numeric_identifiability(ta40, np.random.default_rng(0), 0)
