"""camcal.special and camcal.optimize (numpy-only numerics of calibrate) against scipy as the reference.

scipy is imported freely here: tests are not start-up critical. Tolerances and why:

- ndtr: the same Cephes rational approximations and branches as scipy; only ``exp`` differs
  (numpy's vectorised exp against the C library's, ≤ 1 ulp), observed ≤ 4.6e-16 relative -> rtol 1e-15
  (~4.5 ulp).
- chi2_isf: a different root finder on the same function; stops at 1e-14 relative; the worst case is p -> 1
  with dof < 0.3 (x ~ 1e-200, where dx/x = (2/dof)·dP/P amplifies the rounding of P up to 20x), observed
  1.3e-13 -> rtol 1e-12. chi2_sf: the prefactor exp(a ln x − x − lnΓ(a)) loses ~ε·x, x ≤ ~700 for dof ≤ 200
  -> rtol 1e-12.
- nelder_mead: the same algorithm, constants, ordering and arithmetic: identical iterates -> exact equality.
- least_squares / curve_fit: the same Trust Region Reflective steps; the SVDs (numpy's and scipy's LAPACK
  builds) differ by rounding, so iterates drift apart by ~1e-10 and the two stop at slightly different points
  inside the stopping rule (a step lowering the cost by less than ftol·cost = 1e-8·cost, or a step below
  xtol·‖x‖): both lie within √(2·ftol·cost) of the minimum, i.e. ≤ 1e-4·√(2 cost) standard errors. Asserted:
  costs equal to 1e-8 relative, x equal to 1e-3 standard errors (from JᵀJ) or 1e-7 relative, whichever is larger.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import scipy.optimize as so
import scipy.special as sp
from scipy.optimize._numdiff import approx_derivative  # scipy's finite-difference Jacobian (private module)

from camcal.optimize import (
    covariance_from_jacobian,
    curve_fit,
    forward_difference_jacobian,
    least_squares,
    nelder_mead,
)
from camcal.special import chi2_isf, chi2_sf, gammainc_upper, ndtr

RNG_SEED = 20261128


# ---- ndtr -----------------------------------------------------------------------------------------------------


def _grid() -> np.ndarray:
    rng = np.random.default_rng(RNG_SEED)
    edges = np.array([0.0, -0.0, 1.0, -1.0, math.sqrt(2), -math.sqrt(2), np.nextafter(math.sqrt(2), 0),
                      -np.nextafter(math.sqrt(2), 0), 8.0, -8.0, 8 * math.sqrt(2), -8 * math.sqrt(2), 26.5, -26.5,
                      37.5, -37.5, 38.4, -38.4, 39.0, -39.0, 1e-300, -1e-300, 5e-324, 1e300, -1e300])
    return np.concatenate([rng.normal(0.0, 3.0, 100_000), rng.uniform(-40, 40, 20_000), np.linspace(-40, 40, 8001),
                           edges])


def test_ndtr_matches_scipy():
    x = _grid()
    a, b = ndtr(x), sp.ndtr(x)
    assert a.shape == x.shape and a.dtype == np.float64
    normal = np.abs(b) >= np.finfo(float).tiny  # below: subnormal results, compare absolutely
    np.testing.assert_allclose(a[normal], b[normal], rtol=1e-15, atol=0)
    np.testing.assert_allclose(a[~normal], b[~normal], rtol=0, atol=1e-320)


def test_ndtr_special_values():
    x = np.array([np.nan, np.inf, -np.inf])
    np.testing.assert_array_equal(ndtr(x), [np.nan, 1.0, 0.0])
    assert ndtr(0.0) == 0.5 and np.ndim(ndtr(0.0)) == 0
    assert ndtr(np.zeros((2, 3))).shape == (2, 3)


def test_ndtr_is_the_integral_of_the_normal_density():
    """Independent of scipy: Φ' = φ (central differences), Φ(x) + Φ(−x) = 1, and a deep-tail asymptote."""
    x = np.linspace(-6, 0, 121)  # the lower half, where Φ keeps its relative precision
    h = 1e-5
    deriv = (ndtr(x + h) - ndtr(x - h)) / (2 * h)  # truncation h²|φ''|/6 ≲ 1e-10 relative
    np.testing.assert_allclose(deriv, np.exp(-x * x / 2) / math.sqrt(2 * math.pi), rtol=1e-8)
    x = np.linspace(-6, 6, 241)
    np.testing.assert_allclose(ndtr(x) + ndtr(-x), 1.0, rtol=0, atol=2.3e-16)
    # Mills ratio: Φ(−x) ≈ φ(x)/x (1 − 1/x² + 3/x⁴ − 15/x⁶ + 105/x⁸), next term 945/x¹⁰ ≤ 1e-10 at x ≥ 20
    t = np.array([20.0, 30.0])
    series = 1 - 1 / t**2 + 3 / t**4 - 15 / t**6 + 105 / t**8
    np.testing.assert_allclose(ndtr(-t), np.exp(-t * t / 2) / (t * math.sqrt(2 * math.pi)) * series, rtol=2e-10)


# ---- chi-square -----------------------------------------------------------------------------------------------


def _chi2_cases() -> list[tuple[float, float]]:
    rng = np.random.default_rng(RNG_SEED)
    ps = [1e-300, 1e-100, 1e-20, 1e-12, 1e-6, 1e-3, 0.01, 0.05, 0.5, 0.5000001, 0.9, 0.999, 1 - 1e-9, 1 - 1e-15]
    dofs = [0.1, 0.5, 1, 1.5, 2, 3, 4.5, 7, 15, 30, 31.5, 99, 500, 2000]
    cases = [(p, d) for p in ps for d in dofs]
    cases += [(float(10 ** rng.uniform(-30, 0)), float(10 ** rng.uniform(-1, 3.3))) for _ in range(600)]
    cases += [(float(1 - 10 ** rng.uniform(-15, -0.3)), float(10 ** rng.uniform(-1, 3.3))) for _ in range(200)]
    return cases


def test_chi2_isf_matches_scipy_chdtri():
    worst = 0.0
    for p, dof in _chi2_cases():
        ours, ref = chi2_isf(p, dof), float(sp.chdtri(dof, p))
        worst = max(worst, abs(ours - ref) / ref)
    assert worst <= 1e-12


def test_chi2_isf_inverts_chi2_sf():
    """Round trip (can fail on a wrong derivative or a wrong branch): sf(isf(p)) = p."""
    for p in (1e-12, 1e-6, 0.01, 0.3, 0.5):
        for dof in (1.0, 2.0, 3.0, 7.5, 15.0, 31.0, 120.0):
            assert chi2_sf(chi2_isf(p, dof), dof) == pytest.approx(p, rel=1e-12)
    # the bound camcal.dark uses for noisy pixels (16 frames)
    assert chi2_isf(1e-6, 15.0) == pytest.approx(float(sp.chdtri(15.0, 1e-6)), rel=1e-13)
    assert 56.49 < chi2_isf(1e-6, 15.0) < 56.50
    # dof = 2: Q(1, x/2) = exp(−x/2) exactly
    for p in (1e-200, 1e-6, 0.25, 0.75, 1 - 1e-12):
        assert chi2_isf(p, 2.0) == pytest.approx(-2.0 * math.log(p), rel=1e-13)


def test_chi2_sf_matches_scipy_chdtrc():
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(2000):
        dof = float(10 ** rng.uniform(-1, math.log10(200)))
        x = float(sp.chdtri(dof, 10 ** rng.uniform(-200, -1e-3)))
        assert chi2_sf(x, dof) == pytest.approx(float(sp.chdtrc(dof, x)), rel=1e-12, abs=0)
    for a in (0.05, 0.5, 1.0, 3.3, 50.0):
        for x in (1e-8, 0.1, a, a + 1.0, 3 * a + 5):
            assert gammainc_upper(a, x) == pytest.approx(float(sp.gammaincc(a, x)), rel=1e-13, abs=1e-300)


def test_chi2_edge_cases():
    assert chi2_isf(0.0, 4.0) == math.inf
    assert chi2_isf(1.0, 4.0) == 0.0
    for bad in ((-0.1, 4.0), (1.1, 4.0), (0.5, 0.0), (0.5, -1.0), (math.nan, 3.0)):
        assert math.isnan(chi2_isf(*bad)) and math.isnan(float(sp.chdtri(bad[1], bad[0])))
    assert chi2_sf(0.0, 3.0) == 1.0 and chi2_sf(-1.0, 3.0) == 1.0
    assert chi2_sf(math.inf, 3.0) == 0.0
    assert math.isnan(chi2_sf(1.0, 0.0)) and math.isnan(chi2_sf(math.nan, 3.0))


# ---- Nelder–Mead ----------------------------------------------------------------------------------------------


def _scipy_nm(f, x0, **opt):
    return so.minimize(f, x0, method="Nelder-Mead", options=opt)


@pytest.mark.parametrize("x0", [[-1.2, 1.0], [0.0, 0.0, 0.0], [1.3, 0.7, 0.8, 1.9, 1.2]])
def test_nelder_mead_same_iterates_as_scipy_rosenbrock(x0):
    ours = nelder_mead(so.rosen, x0, xatol=1e-8, fatol=1e-8, maxiter=4000)
    ref = _scipy_nm(so.rosen, x0, xatol=1e-8, fatol=1e-8, maxiter=4000)
    np.testing.assert_array_equal(ours.x, ref.x)
    assert (ours.fun, ours.nit, ours.nfev, ours.success) == (ref.fun, ref.nit, ref.nfev, ref.success)
    assert ours.success and ours.fun < 1e-12


def test_nelder_mead_same_iterates_as_scipy_random_problems():
    """Random quadratics, a quartic and a non-smooth function, from random starts (some coordinates zero)."""
    rng = np.random.default_rng(RNG_SEED)
    for k in range(30):
        n = int(rng.integers(1, 6))
        a = rng.normal(size=(n, n))
        h = a @ a.T + 0.1 * np.eye(n)
        c = rng.normal(size=n)
        kind = k % 3
        if kind == 0:
            def f(x, h=h, c=c):
                return float((x - c) @ h @ (x - c))
        elif kind == 1:
            def f(x, c=c):
                return float(np.sum((x - c) ** 4) + np.sum(x**2))
        else:
            def f(x, c=c):
                return float(np.sum(np.abs(x - c)))
        x0 = rng.normal(size=n) * (rng.random(n) > 0.3)
        opts = {"xatol": 10 ** rng.uniform(-8, -3), "fatol": 10 ** rng.uniform(-8, -3), "maxiter": 2000}
        ours = nelder_mead(f, x0, **opts)
        ref = _scipy_nm(f, x0, **opts)
        np.testing.assert_array_equal(ours.x, ref.x)
        assert (ours.fun, ours.nit, ours.nfev, ours.status) == (ref.fun, ref.nit, ref.nfev, ref.status)


def test_nelder_mead_budgets_and_initial_simplex():
    ours = nelder_mead(so.rosen, [-1.2, 1.0], maxiter=20)
    ref = _scipy_nm(so.rosen, [-1.2, 1.0], maxiter=20)
    assert not ours.success and ours.status == ref.status == 2
    np.testing.assert_array_equal(ours.x, ref.x)
    ours = nelder_mead(so.rosen, [-1.2, 1.0], maxfev=15)
    ref = _scipy_nm(so.rosen, [-1.2, 1.0], maxfev=15)
    assert not ours.success and ours.status == ref.status == 1 and ours.nfev == ref.nfev == 15
    np.testing.assert_array_equal(ours.x, ref.x)
    seen = []
    nelder_mead(lambda x: seen.append(x.copy()) or float(x @ x), [2.0, 0.0], maxfev=3)
    np.testing.assert_array_equal(seen, [[2.0, 0.0], [2.1, 0.0], [2.0, 0.00025]])  # the 5 % / 0.00025 rule


def test_nelder_mead_on_the_dark_likelihood_same_as_scipy():
    """The quantised-normal likelihood of camcal.dark (with camcal's ndtr) minimised by both: same point."""
    rng = np.random.default_rng(RNG_SEED)
    mu = 60 + 0.3 * rng.normal(size=4000)
    k1 = np.round(mu + 0.38 * rng.normal(size=mu.size)).astype(int)
    k2 = np.round(mu + 0.1 + 0.38 * rng.normal(size=mu.size)).astype(int)
    lo, n = 57, 7
    hist = np.bincount((k1 - lo) * n + (k2 - lo), minlength=n * n).reshape(n, n).astype(float)
    edges = np.arange(n + 1) - 0.5 + 0.0
    nodes, weights = np.polynomial.hermite_e.hermegauss(48)
    weights = weights / weights.sum()

    def nll(p):
        m, o, lsd, ls = p
        sd, sg = np.exp(lsd), np.exp(ls)
        mq = m + sd * nodes
        p1 = np.diff(ndtr((edges[None, :] - mq[:, None]) / sg), axis=1)
        p2 = np.diff(ndtr((edges[None, :] - (mq[:, None] + o)) / sg), axis=1)
        prob = 0.9999 * np.einsum("q,qi,qj->ij", weights, p1, p2) + 1e-4 / (n * n)
        return -float(np.sum(hist * np.log(prob)))

    x0 = [float(k1.mean() - lo), 0.0, math.log(0.3), math.log(0.4)]
    ours = nelder_mead(nll, x0, xatol=1e-5, fatol=1e-4, maxiter=4000)
    ref = _scipy_nm(nll, x0, xatol=1e-5, fatol=1e-4, maxiter=4000)
    np.testing.assert_array_equal(ours.x, ref.x)
    assert math.exp(ours.x[3]) == pytest.approx(0.38, abs=0.03)  # σ recovered (4000 pixels: ~2 % noise)


# ---- least squares --------------------------------------------------------------------------------------------


def _assert_same_optimum(ours, ref, *, xtol=1e-8):
    """Costs within ftol, x within 1e-3 standard errors (from scipy's JᵀJ) or 1e-7 relative."""
    assert ours.success and ref.success
    assert ours.cost == pytest.approx(ref.cost, rel=1e-8, abs=1e-20)
    try:
        se = np.sqrt(np.diag(np.linalg.inv(ref.jac.T @ ref.jac)))
    except np.linalg.LinAlgError:
        se = np.zeros_like(ref.x)
    tol = np.maximum(1e-3 * se, 1e-7 * np.abs(ref.x) + xtol)
    assert np.all(np.abs(ours.x - ref.x) <= tol), (ours.x, ref.x, tol)
    np.testing.assert_array_equal(ours.active_mask, ref.active_mask)


def _decay_problem(seed: int):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 10, 50)
    y = 3 * np.exp(-0.4 * t) + 0.5 + rng.normal(0, 0.02, t.size)
    return lambda p: p[0] * np.exp(-p[1] * t) + p[2] - y


@pytest.mark.parametrize("bounds", [(-np.inf, np.inf), ([0, 0, 0], [10, 1, 0.3]), ([0, 0.5, -1], [10, 1, 1])])
@pytest.mark.parametrize("x_scale", [None, "jac", [1.0, 0.1, 1.0]])
@pytest.mark.parametrize("diff_step", [None, 1e-4])
def test_least_squares_same_optimum_as_scipy(bounds, x_scale, diff_step):
    """Unbounded, a bound active at the optimum (c ≤ 0.3 and k ≥ 0.5 cut the free optimum c ≈ 0.5, k ≈ 0.4)."""
    fun = _decay_problem(1)
    x0 = [1.0, 0.6, 0.1]
    ours = least_squares(fun, x0, bounds=bounds, x_scale=x_scale, diff_step=diff_step)
    ref = so.least_squares(fun, x0, bounds=bounds, x_scale=1.0 if x_scale is None else x_scale, diff_step=diff_step)
    _assert_same_optimum(ours, ref)
    if np.isfinite(bounds[0][0] if np.ndim(bounds[0]) else bounds[0]):
        assert ours.active_mask.any()  # the optimum sits on a bound
        on = ours.active_mask != 0
        bound = np.where(ours.active_mask > 0, bounds[1], bounds[0])[on]
        assert np.all(np.abs(ours.x[on] - bound) <= 1e-8 * (1 + np.abs(bound)))


def test_least_squares_rosenbrock_on_a_bound():
    """scipy's documented example: Rosenbrock residuals with x1 ≥ 1.5 -> (1.22437075, 1.5)."""
    def fun(x):
        return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])

    ours = least_squares(fun, [2.0, 2.0], bounds=([-np.inf, 1.5], np.inf))
    ref = so.least_squares(fun, [2.0, 2.0], bounds=([-np.inf, 1.5], np.inf))
    _assert_same_optimum(ours, ref)
    np.testing.assert_allclose(ours.x, [1.22437075, 1.5], atol=1e-7)
    np.testing.assert_array_equal(ours.active_mask, [0, -1])


def test_least_squares_random_problems_same_as_scipy():
    """Random power-law and exponential fits with random bounds (some active), x_scale 'jac' or 1."""
    rng = np.random.default_rng(RNG_SEED)
    for k in range(40):
        m = int(rng.integers(6, 300))
        u = np.sort(rng.uniform(0.05, 3.0, m))
        truth = np.array([rng.uniform(10, 2000), rng.uniform(0.3, 1.5), rng.uniform(-50, 100)])
        sig = rng.uniform(0.5, 5.0, m)
        y = truth[0] * u ** truth[1] + truth[2] + sig * rng.normal(size=m)

        def fun(p, u=u, y=y, sig=sig):
            return (p[0] * np.power(u, p[1]) + p[2] - y) / sig

        lb = np.array([0.0, 0.02, -np.inf])
        ub = np.array([np.inf, 10.0, np.inf])
        if k % 3 == 1:
            ub[1] = truth[1] * 0.9  # optimum on the upper bound of γ
        x0 = np.array([truth[0] * rng.uniform(0.5, 2), min(1.0, ub[1] * 0.99), 0.0])
        xs = "jac" if k % 2 else None
        ours = least_squares(fun, x0, bounds=(lb, ub), x_scale=xs, max_nfev=20000)
        ref = so.least_squares(fun, x0, bounds=(lb, ub), x_scale=xs if xs else 1.0, max_nfev=20000)
        _assert_same_optimum(ours, ref)
        if k % 3 == 1:
            assert ours.active_mask[1] == 1


def test_least_squares_never_leaves_the_bounds():
    """Every evaluation (finite differences included) lies inside the box, although the free optimum does not."""
    lb, ub = np.array([0.0, 1.0]), np.array([0.5, 3.0])

    def fun(x):
        assert np.all(x >= lb) and np.all(x <= ub), x
        return np.array([x[0] - 2.0, 0.1 * (x[1] - 0.0), x[0] * x[1] - 4.0])

    res = least_squares(fun, [0.5, 3.0], bounds=(lb, ub), diff_step=1e-4)  # starts on the upper bounds
    assert res.success and np.all(res.x >= lb) and np.all(res.x <= ub)
    assert res.x[0] == pytest.approx(0.5, abs=1e-8) and res.x[1] == pytest.approx(3.0, abs=1e-8)


def test_least_squares_failures():
    fun = _decay_problem(2)
    res = least_squares(fun, [1.0, 0.1, 0.0], max_nfev=3)
    assert res.status == 0 and not res.success and res.nfev == 3
    with pytest.raises(ValueError, match="outside"):
        least_squares(fun, [1.0, 2.0, 0.0], bounds=([0, 0, 0], [10, 1, 1]))
    with pytest.raises(ValueError, match="strictly less"):
        least_squares(fun, [1.0, 0.5, 0.0], bounds=([0, 1, 0], [10, 1, 1]))
    with pytest.raises(ValueError, match="not finite"):
        least_squares(lambda p: np.array([np.nan, p[0]]), [1.0])
    with pytest.raises(ValueError, match="x_scale"):
        least_squares(fun, [1.0, 0.1, 0.0], x_scale=[1.0, -1.0, 1.0])


def test_forward_difference_jacobian_against_analytic():
    """A wrong derivative or step rule fails: the analytic Jacobian of a smooth model, and scipy's own estimate."""
    t = np.linspace(0.1, 4, 30)

    def fun(p):
        return p[0] * np.exp(-p[1] * t) + p[2] * np.sin(t)

    def jac(p):
        return np.stack([np.exp(-p[1] * t), -p[0] * t * np.exp(-p[1] * t), np.sin(t)], axis=1)

    p = np.array([2.0, 0.7, -0.3])
    lb, ub = np.full(3, -np.inf), np.full(3, np.inf)
    j = forward_difference_jacobian(fun, p, fun(p), lb, ub)
    np.testing.assert_allclose(j, jac(p), rtol=1e-6, atol=1e-7)  # forward differences: O(√ε) error
    for rel in (None, 1e-4):
        for lo, hi in ((lb, ub), (np.array([0, 0, -1]), np.array([2.0, 1, 1]))):  # p[0] on its upper bound
            ours = forward_difference_jacobian(fun, p, fun(p), lo, hi, rel)
            ref = approx_derivative(fun, p, method="2-point", rel_step=rel, f0=fun(p), bounds=(lo, hi))
            np.testing.assert_array_equal(ours, ref)
    wrong = forward_difference_jacobian(lambda q: fun(q) + 1e-3 * q[1] ** 2, p, fun(p) + 1e-3 * p[1] ** 2, lb, ub)
    assert not np.allclose(wrong, jac(p), rtol=1e-6, atol=1e-7)


# ---- curve_fit ------------------------------------------------------------------------------------------------


def _eq12(x, a, g, b):
    return a * np.power(x, g) + b


def test_curve_fit_matches_scipy_absolute_sigma():
    rng = np.random.default_rng(RNG_SEED)
    bounds = ([0.0, 0.02, -np.inf], [np.inf, 10.0, np.inf])
    for _ in range(40):
        m = int(rng.integers(4, 40))
        x = np.sort(rng.uniform(0.01, 1, m))
        u = x / np.exp(np.mean(np.log(x)))
        s = rng.uniform(0.5, 5, m)
        y = _eq12(u, 1000, rng.uniform(0.3, 1.5), 64) + rng.normal(0, 1, m) * s
        p0 = [900.0, 1.0, 60.0]
        popt, pcov = curve_fit(_eq12, u, y, p0, sigma=s, bounds=bounds, x_scale="jac", max_nfev=20000)
        rp, rc = so.curve_fit(_eq12, u, y, p0=p0, sigma=s, absolute_sigma=True, bounds=bounds, method="trf",
                              x_scale="jac", max_nfev=20000)
        se = np.sqrt(np.diag(rc))
        assert np.all(np.abs(popt - rp) <= 1e-3 * se)
        np.testing.assert_allclose(pcov, rc, rtol=1e-4, atol=1e-4 * np.max(np.abs(rc)))


def test_covariance_from_jacobian():
    rng = np.random.default_rng(RNG_SEED)
    j = rng.normal(size=(20, 3)) * [1.0, 100.0, 0.01]
    np.testing.assert_allclose(covariance_from_jacobian(j), np.linalg.inv(j.T @ j), rtol=1e-10)
    # rank-deficient (two equal columns): the pseudo-inverse, not inf
    jd = np.column_stack([j[:, 0], j[:, 0], j[:, 2]])
    np.testing.assert_allclose(covariance_from_jacobian(jd), np.linalg.pinv(jd.T @ jd, rcond=1e-12), rtol=1e-8)
    assert np.all(np.isinf(covariance_from_jacobian(np.full((5, 2), np.nan))))  # not estimable
    np.testing.assert_array_equal(covariance_from_jacobian(np.zeros((5, 2))), np.zeros((2, 2)))  # as scipy


def test_curve_fit_errors_like_scipy():
    u = np.linspace(0.1, 2, 10)
    y = _eq12(u, 100, 1, 5)
    with pytest.raises(ValueError):
        curve_fit(_eq12, u, np.where(u > 1, np.nan, y), [90, 1, 0])
    with pytest.raises(RuntimeError, match="Optimal parameters not found"):
        curve_fit(_eq12, u, y, [1, 3, 0], bounds=([0, 0.02, -np.inf], [np.inf, 10, np.inf]), max_nfev=2)


# ---- calibrate's stages import no scipy ------------------------------------------------------------------------


def test_calibration_numerics_run_without_scipy():
    """In a fresh interpreter where any ``import scipy...`` fails, the stage modules import and fit."""
    code = (
        "import sys; sys.modules['scipy'] = None\n"
        "import numpy as np\n"
        "import camcal.dark, camcal.flat, camcal.response, camcal.reference_targets\n"
        "from camcal.dark import quantised_noise_fit\n"
        "from camcal.response import fit_eq12, fit_srgb_form, srgb_form_encode\n"
        "rng = np.random.default_rng(0)\n"
        "mu = 60 + 0.3 * rng.normal(size=3000)\n"
        "a = np.round(mu + 0.4 * rng.normal(size=mu.size)); b = np.round(mu + 0.4 * rng.normal(size=mu.size))\n"
        "s, d, o = quantised_noise_fit(a, b)\n"
        "assert abs(s - 0.4) < 0.05, s\n"
        "x = np.geomspace(0.01, 1, 9)\n"
        "r = fit_eq12(x, 500 * x ** 0.45 + 3, np.ones(9), gamma0=0.45)\n"
        "assert abs(r['gamma'] - 0.45) < 1e-3, r\n"
        "g = 4095 * srgb_form_encode(x / 0.8, 1 / 2.4)\n"
        "q = fit_srgb_form(x, g, np.ones(9), 4095.0, 0.5, 1.0)\n"
        "assert abs(q['exponent'] - 1 / 2.4) < 1e-6 and abs(q['x_white_s'] - 0.8) < 1e-6, q\n"
        "assert 'scipy' not in {m.split('.')[0] for m in sys.modules if sys.modules[m] is not None}\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok"
