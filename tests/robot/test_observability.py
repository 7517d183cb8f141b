import numpy as np
import pytest

from bench.robot.identifiability import closed_form_reduction
from bench.robot.observability import INDICES, observability_indices, select_poses


def test_indices_relations(ta40, rng):
    red = closed_form_reduction(ta40)
    q = ta40.random_configurations(rng, 40)
    o = observability_indices(ta40, q, red.kept)
    assert set(o) == set(INDICES)
    assert 0 < o["O2"] <= 1
    assert o["O4"] == pytest.approx(o["O3"] * o["O2"])


@pytest.mark.parametrize("index", INDICES)
def test_selection_beats_random_poses(ta40, rng, index):
    red = closed_form_reduction(ta40)
    _, value = select_poses(ta40, red.kept, 30, rng, index, n_candidates=300, exchange_passes=1)
    random_values = [observability_indices(ta40, ta40.random_configurations(rng, 30), red.kept)[index]
                     for _ in range(20)]
    assert value > max(random_values)


def test_selected_poses_are_within_limits(ta40, rng):
    red = closed_form_reduction(ta40)
    q, _ = select_poses(ta40, red.kept, 12, rng, "O3", n_candidates=100, exchange_passes=0)
    assert q.shape == (12, 6)
    assert np.all(q >= ta40.q_min) and np.all(q <= ta40.q_max)


def test_bad_arguments(ta40, rng):
    red = closed_form_reduction(ta40)
    with pytest.raises(ValueError, match="index"):
        select_poses(ta40, red.kept, 30, rng, "O9")
    with pytest.raises(ValueError, match="n_poses"):
        select_poses(ta40, red.kept, 5, rng)
