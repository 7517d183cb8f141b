import numpy as np
import pytest

from bench.robot.identifiability import closed_form_reduction
from bench.robot.identification import identify_iterative, identify_linear
from bench.robot.jacobian import identification_jacobian
from bench.robot.kinematics import ee_position
from bench.robot.model import random_errors


@pytest.fixture(scope="module")
def red(ta40):
    return closed_form_reduction(ta40)


def _truth(rng):
    eps = random_errors(rng)
    eps[36:] = 0.0  # as in Table 2: no errors in frame 6 (makes the 25-parameter exact model exact)
    return eps


def test_linear_noise_free_is_exact(ta40, red, rng):
    eps = _truth(rng)
    q = ta40.random_configurations(rng, 100)
    pts = ee_position(ta40, q) + identification_jacobian(ta40, q) @ eps  # Eq. 12
    res = identify_linear(ta40, q, pts, red)
    assert res.success
    assert np.abs(res.eps_dot - red.reduce(eps)).max() < 1e-12
    assert res.residual_rms < 1e-12


def test_iterative_exact_noise_free_reproduces_heldout(ta40, red, rng):
    eps = _truth(rng)
    q, qh = ta40.random_configurations(rng, 100), ta40.random_configurations(rng, 500)
    res = identify_iterative(ta40, q, ee_position(ta40, q, eps), red, sigma=5e-5)
    assert res.success and res.iterations < 20
    err = np.linalg.norm(ee_position(ta40, qh, res.eps) - ee_position(ta40, qh, eps), axis=-1)
    assert err.max() < 1e-9  # m, i.e. 1e-6 mm
    # first-order agreement with the linear reduction (second-order terms ~ eps^2 * reach)
    assert np.abs(res.eps_dot - red.reduce(eps))[:].max() < 5e-4


def test_covariance_matches_monte_carlo(ta40, red, rng):
    """Normalised estimation errors e^T C^-1 e over 40 noise draws: chi-square with 40 * 25 dof."""
    eps = _truth(rng)
    sigma = 5e-5
    q = ta40.random_configurations(rng, 100)
    p = ee_position(ta40, q, eps)
    ref = identify_iterative(ta40, q, p, red, sigma=sigma)
    total, n = 0.0, 40
    for _ in range(n):
        r = identify_iterative(ta40, q, p + rng.normal(scale=sigma, size=p.shape), red, sigma=sigma, eps0=ref.eps)
        e = r.eps_dot - ref.eps_dot
        total += e @ np.linalg.solve(r.covariance, e)
    dof = n * len(red.kept)
    assert abs(total - dof) < 4 * np.sqrt(2 * dof)  # 4 sigma of the chi-square distribution


def test_weights_follow_sigma(ta40, red, rng):
    q = ta40.random_configurations(rng, 50)
    p = ee_position(ta40, q)
    a = identify_linear(ta40, q, p, red, sigma=1e-4)
    b = identify_linear(ta40, q, p, red, sigma=2e-4)
    assert np.allclose(b.covariance, 4 * a.covariance)


def test_too_few_poses_is_a_result_not_an_exception(ta40, red, rng):
    q = ta40.random_configurations(rng, 5)
    for f in (identify_linear, identify_iterative):
        res = f(ta40, q, ee_position(ta40, q), red)
        assert not res.success and "poses" in res.message


def test_rank_deficient_poses(ta40, red):
    q = np.tile(np.deg2rad([10, 30, 60, 0, 20, 0]), (20, 1))  # one pose repeated
    for f in (identify_linear, identify_iterative):
        res = f(ta40, q, ee_position(ta40, q), red)
        assert not res.success and "rank deficient" in res.message


def test_bad_measurements(ta40, red, rng):
    q = ta40.random_configurations(rng, 20)
    p = ee_position(ta40, q)
    p[3, 1] = np.nan
    with pytest.raises(ValueError, match="points"):
        identify_linear(ta40, q, p, red)
    with pytest.raises(ValueError, match="sigma"):
        identify_linear(ta40, q, ee_position(ta40, q), red, sigma=-1.0)
    with pytest.raises(ValueError, match="shape"):
        identify_linear(ta40, q, ee_position(ta40, q)[:-1], red)


def test_chi2_consistency_check(ta40, red, rng):
    """Points in mm where metres belong are refused (they were accepted as success=True by the linear solver and
    reported as 'not converged' by the iterative one); model error and overstated sigma are warned; consistent
    noisy data gives chi2/dof ~ 1 and no warning."""
    eps = _truth(rng)
    sigma = 5e-5
    q = ta40.random_configurations(rng, 60)
    p = ee_position(ta40, q, eps) + rng.normal(scale=sigma, size=(60, 3))
    for f in (identify_linear, identify_iterative):
        bad = f(ta40, q, p * 1e3, red, sigma=sigma)
        assert not bad.success and "mm given as m?" in bad.message and np.all(np.isnan(bad.eps))
        assert bad.chi2_per_dof > 1e4
    good = identify_iterative(ta40, q, p, red, sigma=sigma)
    assert good.success and "WARNING" not in good.message and 0.7 < good.chi2_per_dof < 1.3
    lin = identify_linear(ta40, q, p, red, sigma=sigma)  # the linearised model on exact data: model error
    assert lin.success and "WARNING chi2/dof" in lin.message and "optimistic" in lin.message
    over = identify_iterative(ta40, q, p, red, sigma=100 * sigma)  # sigma overstated (e.g. mm given as um)
    assert over.success and "pessimistic" in over.message and over.chi2_per_dof < 1e-3
    mixed = identify_linear(ta40, q, p[::-1], red, sigma=sigma)  # readings and points paired wrongly
    assert not mixed.success and "refused" in mixed.message and "another frame?" in mixed.message


def test_iterative_claims_no_convergence_it_did_not_reach(ta40, red, rng, monkeypatch):
    """A run in which no step lowers the cost has converged only if it started at a minimum. The hand-written loop
    this replaced said 'converged' whenever its damping gave up (every trial step raised the cost) and returned its
    start as the estimate - here with a Jacobian of the wrong sign, a few predicted standard deviations from the
    minimum; running out of evaluations is not convergence either."""
    import bench.robot.identification as identification

    eps, sigma = _truth(rng), 5e-5
    q = ta40.random_configurations(rng, 60)
    p = ee_position(ta40, q, eps) + rng.normal(scale=sigma, size=q[:, :3].shape)
    opt = identify_iterative(ta40, q, p, red, sigma=sigma)
    assert opt.success
    at = identify_iterative(ta40, q, p, red, sigma=sigma, eps0=opt.eps)  # started at the minimum: converged there
    assert at.success and "WARNING" not in at.message and np.abs(at.eps - opt.eps).max() < 1e-12
    start = opt.eps.copy()
    start[red.kept] += np.linalg.cholesky(opt.covariance) @ rng.normal(size=len(red.kept)) * 2  # ~10 sigma^2 off
    jacobian = identification.identification_jacobian
    monkeypatch.setattr(identification, "identification_jacobian", lambda *a, **k: -jacobian(*a, **k))
    uphill = identify_iterative(ta40, q, p, red, sigma=sigma, eps0=start)
    assert not uphill.success and "no step lowered the cost" in uphill.message
    assert uphill.cost > opt.cost + 1 and uphill.chi2_per_dof < 2  # the start, still consistent with sigma
    monkeypatch.undo()
    few = identify_iterative(ta40, q, p, red, sigma=sigma, max_nfev=2)
    assert not few.success and "max_nfev" in few.message
