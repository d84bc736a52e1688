"""camcal.spline (numpy-only cubic splines) against scipy.interpolate.CubicSpline, the reference.

Tolerance: 1e-12 of the scale of what is compared (the largest |reference| over the evaluation
points, or max|y| / span^nu when that is larger, so that a derivative which is zero in exact
arithmetic is not compared to its own rounding noise). Both sides solve the same tridiagonal
system in float64 (scipy with LAPACK's pivoted band solver, camcal without pivoting on a
diagonally dominant system) and evaluate the same Hermite pieces, so they agree to rounding:
on 3 000 random splines (2–80 knots, spacing ratios up to 20, values scaled 1e-6..1e6,
extrapolation to 20 % beyond the ends) the worst difference was 7e-14 of that scale, and 9e-13
with knot spacings that differ by 10^4 (the condition of the system grows with that ratio, for
scipy too). A wrong end condition, a wrong derivative factor or an off-by-one piece shows at
1e-3 or more, as the tests marked "can fail" demonstrate.
"""

from __future__ import annotations

import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from camcal.radiance import FWHM_TO_SIGMA as RADIANCE_FWHM_TO_SIGMA
from camcal.radiance import radiance_model
from camcal.spectra import camera_sensitivities
from camcal.spectral import FWHM_TO_SIGMA, SpectralSensitivity, slit_function, slit_matrix
from camcal.spline import PiecewiseCubic, cubic_spline

RTOL = 1e-12
BCS = ("not-a-knot", "natural")


def _knots(rng: np.random.Generator, n: int, ratio: float = 20.0) -> np.ndarray:
    """n strictly increasing knots with spacings between 1 and ``ratio`` (times a random scale), anywhere."""
    scale = 10.0 ** rng.uniform(-3, 3)
    return rng.uniform(-1e3, 1e3) + scale * np.cumsum(rng.uniform(1.0, ratio, n))


def _points(rng: np.random.Generator, x: np.ndarray, m: int = 60) -> np.ndarray:
    """Evaluation points: every knot, random points inside and 20 % beyond either end, knot midpoints."""
    span = x[-1] - x[0]
    return np.concatenate([x, rng.uniform(x[0] - 0.2 * span, x[-1] + 0.2 * span, m), 0.5 * (x[1:] + x[:-1])])


def _assert_close(ref: np.ndarray, got: np.ndarray, y: np.ndarray, span: float, nu: int) -> None:
    assert got.shape == ref.shape
    assert np.array_equal(np.isnan(ref), np.isnan(got))
    ok = ~np.isnan(ref)
    if not ok.any():
        return
    scale = max(float(np.abs(ref[ok]).max()), float(np.abs(y).max()) / span**nu)
    np.testing.assert_allclose(got[ok], ref[ok], rtol=0, atol=RTOL * scale)


# ---- agreement with scipy ------------------------------------------------------------------------
@pytest.mark.parametrize("bc", BCS)
@pytest.mark.parametrize("n", [2, 3, 4, 5, 6, 9, 31, 300])
@pytest.mark.parametrize("tail", [(), (3,), (2, 4)])
def test_matches_scipy_on_random_data(bc, n, tail):
    """Value and derivatives 1-4, inside, on the knots and extrapolated, for 1-D and N-D values."""
    rng = np.random.default_rng(1000 * n + len(tail) + (bc == "natural"))
    for _ in range(8):
        x = _knots(rng, n)
        y = rng.normal(size=(n,) + tail) * 10.0 ** rng.uniform(-6, 6)
        ref, got = CubicSpline(x, y, bc_type=bc), cubic_spline(x, y, bc)
        t = _points(rng, x)
        for nu in range(5):
            _assert_close(ref(t, nu), got(t, nu), y, x[-1] - x[0], nu)


@pytest.mark.parametrize("bc", BCS)
def test_matches_scipy_with_uneven_spacing(bc):
    """Neighbouring spacings differing by up to 100x (observed: 3e-13 for the third derivative, 1e-13 otherwise)."""
    rng = np.random.default_rng(7)
    for n in (4, 5, 12, 80):
        for _ in range(10):
            x = np.cumsum(np.exp(rng.uniform(0.0, np.log(100.0), n)))
            y = rng.normal(size=n)
            t = _points(rng, x)
            for nu in range(4):
                _assert_close(CubicSpline(x, y, bc_type=bc)(t, nu), cubic_spline(x, y, bc)(t, nu), y, x[-1] - x[0], nu)


def _exact_slopes(x: np.ndarray, y: np.ndarray, bc: str) -> np.ndarray:
    """The knot slopes of the spline in exact rational arithmetic (the same equations, no rounding)."""
    n = x.size
    X, Y = [Fraction(float(v)) for v in x], [Fraction(float(v)) for v in y]
    dx = [X[i + 1] - X[i] for i in range(n - 1)]
    m = [(Y[i + 1] - Y[i]) / dx[i] for i in range(n - 1)]
    rows = [[Fraction(0)] * 4 for _ in range(n)]  # lower, diag, upper, rhs
    for i in range(1, n - 1):
        rows[i] = [dx[i], 2 * (dx[i - 1] + dx[i]), dx[i - 1], 3 * (dx[i] * m[i - 1] + dx[i - 1] * m[i])]
    if bc == "natural":
        rows[0] = [Fraction(0), 2 * dx[0], dx[0], 3 * (Y[1] - Y[0])]
        rows[-1] = [dx[-1], 2 * dx[-1], Fraction(0), 3 * (Y[-1] - Y[-2])]
    else:
        d0, d1 = X[2] - X[0], X[-1] - X[-3]
        rows[0] = [Fraction(0), dx[1], d0, ((dx[0] + 2 * d0) * dx[1] * m[0] + dx[0] ** 2 * m[1]) / d0]
        rows[-1] = [d1, dx[-2], Fraction(0), (dx[-1] ** 2 * m[-2] + (2 * d1 + dx[-1]) * dx[-2] * m[-1]) / d1]
    ratio, z = [Fraction(0)] * n, [Fraction(0)] * n
    for i, (lo, di, up, b) in enumerate(rows):
        pivot = di - (lo * ratio[i - 1] if i else 0)
        ratio[i], z[i] = up / pivot, (b - (lo * z[i - 1] if i else 0)) / pivot
    for i in range(n - 2, -1, -1):
        z[i] -= ratio[i] * z[i + 1]
    return np.array([float(v) for v in z])


@pytest.mark.parametrize("bc", BCS)
def test_slopes_as_exact_as_scipy_with_extreme_spacing(bc):
    """Elimination without pivoting is as accurate as scipy's pivoted band solver, spacing ratios up to 10^4.

    Against exact rational arithmetic the knot slopes are right to 3e-14 of their largest value (scipy
    2.5e-14); 1e-12 leaves margin. (Beyond the slopes, the third derivative of such a spline loses
    ~1e-10 to cancellation in float64 for both, which is why the comparison with scipy above stops at 100.)
    """
    rng = np.random.default_rng(7)
    for n in (4, 5, 12, 40):
        for _ in range(3):
            x = np.cumsum(np.exp(rng.uniform(0.0, np.log(1e4), n)))
            y = rng.normal(size=n)
            exact = _exact_slopes(x, y, bc)
            got = cubic_spline(x, y, bc)(x, 1)
            ref = CubicSpline(x, y, bc_type=bc)(x, 1)
            scale = float(np.abs(exact).max())
            assert np.abs(got - exact).max() <= 1e-12 * scale
            assert np.abs(ref - exact).max() <= 1e-12 * scale  # the reference itself is that good


@pytest.mark.parametrize("bc", BCS)
def test_piece_coefficients_match_scipy(bc):
    """Same pieces, same layout as scipy's PPoly.c (highest power first, local in x - x_i)."""
    rng = np.random.default_rng(3)
    x = _knots(rng, 25, ratio=3.0)
    y = rng.normal(size=(25, 2))
    ref, got = CubicSpline(x, y, bc_type=bc), cubic_spline(x, y, bc)
    assert got.coefficients.shape == ref.c.shape == (4, 24, 2)
    for k in range(4):  # the k-th coefficient has the unit of y / x^(3-k)
        np.testing.assert_allclose(got.coefficients[k], ref.c[k], rtol=0, atol=RTOL * np.abs(ref.c[k]).max())
    np.testing.assert_array_equal(got.knots, ref.x)


@pytest.mark.parametrize("bc", BCS)
def test_no_extrapolation_gives_nan_outside_like_scipy(bc):
    rng = np.random.default_rng(11)
    x = _knots(rng, 7)
    y = rng.normal(size=(7, 3))
    t = np.concatenate([_points(rng, x), [np.nan, -np.inf, np.inf]])
    ref, got = CubicSpline(x, y, bc_type=bc, extrapolate=False), cubic_spline(x, y, bc, extrapolate=False)
    for nu in range(5):
        r, g = ref(t, nu), got(t, nu)
        assert np.array_equal(np.isnan(r), np.isnan(g))
        outside = (t < x[0]) | (t > x[-1]) | np.isnan(t)
        assert np.isnan(g[outside]).all() and not np.isnan(g[~outside]).any()
        _assert_close(r, g, y, x[-1] - x[0], nu)


def test_nan_points_give_nan_with_extrapolation():
    x, y = np.arange(5.0), np.array([0.0, 1.0, 0.0, 2.0, 1.0])
    for nu in range(5):
        r, g = CubicSpline(x, y)([np.nan, 1.5], nu), cubic_spline(x, y)([np.nan, 1.5], nu)
        assert np.isnan(g[0]) and np.isnan(r[0])
        assert g[1] == pytest.approx(r[1], rel=RTOL, abs=RTOL)


@pytest.mark.parametrize("shape", [(), (1,), (7,), (3, 5)])
@pytest.mark.parametrize("tail", [(), (4,)])
def test_output_shape_like_scipy(shape, tail):
    rng = np.random.default_rng(5)
    x = np.linspace(0.0, 1.0, 6)
    y = rng.normal(size=(6,) + tail)
    t = rng.uniform(0.0, 1.0, shape) if shape else 0.37
    r, g = CubicSpline(x, y)(t), cubic_spline(x, y)(t)
    assert np.shape(g) == np.shape(r) == shape + tail
    np.testing.assert_allclose(g, r, rtol=RTOL, atol=RTOL)


def test_natural_cardinal_basis_like_scipy_and_linear():
    """``cubic_spline(wl, eye, "natural")(t)`` is scipy's basis; basis @ y is the spline through y; rows sum to 1."""
    rng = np.random.default_rng(2)
    wl = np.arange(400.0, 691.0, 5.0)
    t = np.clip(np.arange(385.0, 705.0, 0.1), wl[0], wl[-1])
    basis = cubic_spline(wl, np.eye(wl.size), "natural")(t)
    assert basis.shape == (t.size, wl.size)
    np.testing.assert_allclose(basis, CubicSpline(wl, np.eye(wl.size), bc_type="natural")(t), rtol=0, atol=RTOL)
    y = rng.normal(size=wl.size)
    np.testing.assert_allclose(basis @ y, cubic_spline(wl, y, "natural")(t), rtol=0, atol=RTOL * np.abs(y).sum())
    # a natural spline through constant data is that constant, so the cardinal functions sum to 1
    np.testing.assert_allclose(basis.sum(axis=1), 1.0, rtol=0, atol=RTOL)


# ---- the special cases and the end conditions themselves (independent of scipy) ---------------------
@pytest.mark.parametrize("bc", BCS)
def test_two_knots_give_the_straight_line(bc):
    x, y = np.array([2.0, 5.0]), np.array([1.0, 7.0])
    s = cubic_spline(x, y, bc)
    t = np.array([0.0, 2.0, 3.3, 5.0, 9.0])
    np.testing.assert_allclose(s(t), 1.0 + 2.0 * (t - 2.0), rtol=1e-15, atol=1e-14)
    np.testing.assert_allclose(s(t, 1), 2.0, rtol=1e-15)
    np.testing.assert_array_equal(s(t, 2), 0.0)


def test_three_knots_not_a_knot_is_the_parabola():
    x = np.array([1.0, 1.5, 4.0])
    y = 3.0 - 2.0 * x + 0.7 * x**2
    t = np.linspace(0.0, 5.0, 41)
    s = cubic_spline(x, y)
    np.testing.assert_allclose(s(t), 3.0 - 2.0 * t + 0.7 * t**2, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(s(t, 2), 1.4, rtol=1e-13)
    np.testing.assert_allclose(s(t, 3), 0.0, atol=1e-12)


def test_four_knots_not_a_knot_is_the_interpolating_cubic():
    """With 4 knots both interior knots are 'not knots': one cubic through the 4 points (np.polyfit, exact)."""
    x = np.array([-1.0, 0.3, 0.9, 2.5])
    y = np.array([0.5, -1.0, 2.0, 0.25])
    poly = np.polyfit(x, y, 3)
    t = np.linspace(-2.0, 3.0, 51)
    s = cubic_spline(x, y)
    for nu in range(4):
        np.testing.assert_allclose(s(t, nu), np.polyval(np.polyder(poly, nu), t), rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("n", [4, 5, 8, 40])
def test_not_a_knot_reproduces_any_cubic_and_natural_does_not(n):
    """Can fail: not-a-knot is exact for cubics; natural (zero end curvature) is not, by far."""
    rng = np.random.default_rng(n)
    x = np.sort(rng.uniform(0.0, 3.0, n)) + np.arange(n) * 0.05
    poly = np.array([0.8, -1.5, 0.3, 2.0])
    y = np.polyval(poly, x)
    t = np.linspace(x[0], x[-1], 101)
    nak, nat = cubic_spline(x, y), cubic_spline(x, y, "natural")
    np.testing.assert_allclose(nak(t), np.polyval(poly, t), rtol=0, atol=1e-11)
    np.testing.assert_allclose(nak(t, 2), np.polyval(np.polyder(poly, 2), t), rtol=0, atol=1e-9)
    assert np.abs(nat(t, 2) - np.polyval(np.polyder(poly, 2), t)).max() > 1e-2


@pytest.mark.parametrize("n", [3, 4, 7, 30])
def test_end_conditions_hold(n):
    """natural: s'' = 0 at both ends; not-a-knot: s''' continuous across x_1 and x_{n-2}; C² everywhere."""
    rng = np.random.default_rng(100 + n)
    x = _knots(rng, n, ratio=4.0)
    y = rng.normal(size=n)
    nat, nak = cubic_spline(x, y, "natural"), cubic_spline(x, y)
    h = float(np.diff(x).min())
    curv = float(np.abs(nat(x, 2)).max())
    assert abs(nat(x[0], 2)) <= 1e-12 * curv and abs(nat(x[-1], 2)) <= 1e-12 * curv
    third = nak.coefficients[0] * 6.0  # constant third derivative of each piece
    assert third[0] == pytest.approx(third[1], rel=1e-10)
    assert third[-1] == pytest.approx(third[-2], rel=1e-10)
    for s in (nat, nak):  # value, slope and curvature continuous at the interior knots
        left = s.coefficients[:, :-1]
        dx = np.diff(x)[:-1]
        for nu in range(3):
            from_left = _piece_value(left, dx, nu)
            np.testing.assert_allclose(from_left, s(x[1:-1], nu), rtol=0,
                                       atol=1e-10 * max(1.0, float(np.abs(s(x, nu)).max())) + 1e-10 * h)


def _piece_value(c: np.ndarray, t: np.ndarray, nu: int) -> np.ndarray:
    """nu-th derivative of the pieces ``c`` (PPoly layout) at local offsets ``t``."""
    powers = np.array([3, 2, 1, 0])
    out = np.zeros_like(t)
    for k, p in enumerate(powers):
        if p >= nu:
            out = out + c[k] * np.prod(np.arange(p - nu + 1, p + 1)) * t ** (p - nu)
    return out


def test_derivatives_agree_with_finite_differences():
    """Can fail: a wrong derivative factor (e.g. 2 instead of 3, or 2 instead of 6) is off by ≥ 30 %."""
    rng = np.random.default_rng(17)
    x = np.cumsum(rng.uniform(0.5, 1.5, 12))
    y = np.sin(x)
    s = cubic_spline(x, y)
    t = 0.5 * (x[1:] + x[:-1])  # piece midpoints: s is a cubic there, central differences are exact to O(h²)
    h = 1e-4
    np.testing.assert_allclose(s(t, 1), (s(t + h) - s(t - h)) / (2 * h), rtol=0, atol=1e-7)
    np.testing.assert_allclose(s(t, 2), (s(t + h, 1) - s(t - h, 1)) / (2 * h), rtol=0, atol=1e-6)
    np.testing.assert_allclose(s(t, 3), (s(t + h, 2) - s(t - h, 2)) / (2 * h), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(s(t, 4), 0.0)


def test_wrong_boundary_condition_or_derivative_is_detected():
    """Can fail: the comparison used above sees a swapped end condition and a swapped derivative order."""
    rng = np.random.default_rng(23)
    x = _knots(rng, 20, ratio=3.0)
    y = rng.normal(size=20)
    t = _points(rng, x)
    span = x[-1] - x[0]
    with pytest.raises(AssertionError):
        _assert_close(CubicSpline(x, y)(t), cubic_spline(x, y, "natural")(t), y, span, 0)
    with pytest.raises(AssertionError):
        _assert_close(CubicSpline(x, y, bc_type="natural")(t), cubic_spline(x, y)(t), y, span, 0)
    with pytest.raises(AssertionError):
        _assert_close(CubicSpline(x, y)(t, 2), cubic_spline(x, y)(t, 1), y, span, 2)
    with pytest.raises(AssertionError):  # extrapolation on where scipy gives NaN
        _assert_close(CubicSpline(x, y, extrapolate=False)(t), cubic_spline(x, y)(t), y, span, 0)


@pytest.mark.parametrize(
    ("x", "y", "kw", "match"),
    [
        ([0.0, 1.0, 1.0, 2.0], [0.0, 1.0, 2.0, 3.0], {}, "strictly increasing"),
        ([0.0, 2.0, 1.0, 3.0], [0.0, 1.0, 2.0, 3.0], {}, "strictly increasing"),
        ([0.0], [1.0], {}, "at least 2"),
        ([0.0, np.nan, 2.0], [0.0, 1.0, 2.0], {}, "finite"),
        ([0.0, 1.0, 2.0], [0.0, np.inf, 2.0], {}, "finite"),
        ([0.0, 1.0, 2.0], [0.0, 1.0], {}, "values along axis 0"),
        ([[0.0, 1.0, 2.0]], [0.0, 1.0, 2.0], {}, "1-dimensional"),
        ([0.0, 1.0, 2.0], [0.0, 1.0, 2.0], {"bc_type": "clamped"}, "unknown boundary condition"),
    ],
)
def test_bad_input_is_refused_like_scipy(x, y, kw, match):
    with pytest.raises(ValueError, match=match):
        cubic_spline(np.array(x), np.array(y), **kw)
    if "bc_type" not in kw and match != "values along axis 0":  # scipy refuses the same data
        with pytest.raises(ValueError):
            CubicSpline(np.array(x), np.array(y))


def test_negative_derivative_order_is_refused():
    s = cubic_spline(np.arange(4.0), np.arange(4.0) ** 2)
    assert isinstance(s, PiecewiseCubic)
    with pytest.raises(ValueError, match="derivative order"):
        s(1.0, -1)


def test_spline_module_needs_no_scipy():
    """camcal.spline must work in an interpreter where any ``import scipy`` fails (start-up rule, issue 17)."""
    code = ("import sys; sys.modules['scipy'] = None\n"
            "import numpy as np\n"
            "from camcal.spline import cubic_spline\n"
            "s = cubic_spline(np.arange(5.0), np.arange(5.0) ** 3)\n"
            "assert abs(float(s(2.5)) - 2.5 ** 3) < 1e-12\n"
            "loaded = [m for m, mod in sys.modules.items() if mod is not None and m.split('.')[0] == 'scipy']\n"
            "assert not loaded, loaded\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


# ---- the callers give what they gave with scipy --------------------------------------------------------
def _noisy_sensitivity(rng: np.random.Generator, deconvolved: bool = False) -> SpectralSensitivity:
    wl = np.arange(400.0, 701.0, 5.0)
    vals = {p: np.exp(-0.5 * ((wl - c) / 25.0) ** 2) + 0.01 * rng.normal(size=wl.size)
            for p, c in zip(("R", "G1", "G2", "B"), (600.0, 540.0, 545.0, 460.0), strict=True)}
    unc = {p: np.full(wl.size, 0.01) for p in vals}
    return SpectralSensitivity(wl, vals, unc, "relative", "relative", bandwidth_nm=5.0, deconvolved=deconvolved)


def test_slit_bias_as_with_scipy():
    s = _noisy_sensitivity(np.random.default_rng(31))
    sigma2 = (5.0 * FWHM_TO_SIGMA) ** 2
    bias = s.slit_bias()
    for p, v in s.values.items():
        ref = 0.5 * sigma2 * CubicSpline(s.wavelength_nm, v)(s.wavelength_nm, 2)
        np.testing.assert_allclose(bias[p], ref, rtol=0, atol=RTOL * np.abs(ref).max())


@pytest.mark.parametrize("shape", ["gaussian", "triangular"])
def test_slit_matrix_as_with_scipy(shape):
    """The deconvolution's forward operator: slit weights times scipy's natural-spline basis."""
    wl = np.arange(400.0, 701.0, 10.0)
    fwhm = np.linspace(4.0, 8.0, wl.size)
    step = 0.1
    reach = 3.0 * float(fwhm.max())
    fine = np.arange(wl[0] - reach, wl[-1] + reach + step / 2, step)
    basis = CubicSpline(wl, np.eye(wl.size), bc_type="natural")(np.clip(fine, wl[0], wl[-1]))
    phi = slit_function(fine[None, :] - wl[:, None], fwhm[:, None], shape)
    phi /= np.trapezoid(phi, fine, axis=1)[:, None]
    weights = np.full(fine.size, step)
    weights[[0, -1]] *= 0.5
    ref = (phi * weights[None, :]) @ basis
    np.testing.assert_allclose(slit_matrix(wl, fwhm, shape, step), ref, rtol=0, atol=RTOL)


def test_radiance_narrowband_as_with_scipy():
    """radiance_model's spline value and curvature at λ0 (second-order slit correction) are scipy's."""
    rng = np.random.default_rng(37)
    wl = np.arange(400.0, 701.0, 5.0)
    c = {k: 1e7 * (np.exp(-0.5 * ((wl - m) / 30.0) ** 2) + 0.01 * rng.uniform(size=wl.size))
         for k, m in zip(("R", "G", "B"), (610.0, 540.0, 460.0), strict=True)}
    u = {k: 0.01 * v for k, v in c.items()}
    model = radiance_model(wl, c, u, target_nm=663.0, line_fwhm_nm=10.0, slit_fwhm_nm=5.0)
    dsig2 = (10.0**2 - 5.0**2) * RADIANCE_FWHM_TO_SIGMA**2
    at = np.array([CubicSpline(wl, c[k])(663.0) + 0.5 * dsig2 * CubicSpline(wl, c[k])(663.0, 2) for k in "RGB"])
    best = int(np.argmax(at))
    assert model.channel == "RGB"[best]
    assert model.weights[best] == pytest.approx(1.0 / at[best], rel=RTOL)
    assert model.weights_unc_rel == pytest.approx(float(CubicSpline(wl, u["RGB"[best]])(663.0)) / at[best], rel=RTOL)


def test_camera_sensitivities_as_with_scipy():
    import colour

    msds = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    wl, vals = np.asarray(msds.wavelengths, float), np.asarray(msds.values, float)
    grid = np.arange(380.0, 781.0, 1.0)
    ref = np.stack([np.clip(np.nan_to_num(CubicSpline(wl, vals[:, i], extrapolate=False)(grid), nan=0.0), 0.0, None)
                    for i in range(3)])
    np.testing.assert_allclose(camera_sensitivities("nikon-d5100", grid), ref, rtol=0, atol=RTOL)


def test_spectral_callers_run_without_scipy_interpolate(monkeypatch):
    """Can fail: with ``scipy.interpolate`` unimportable, the sweep stage's spline uses still work."""
    s = _noisy_sensitivity(np.random.default_rng(41))
    monkeypatch.setitem(sys.modules, "scipy.interpolate", None)  # any `from scipy.interpolate import` raises
    with pytest.raises(ImportError):
        from scipy.interpolate import CubicSpline as _  # noqa: F401
    assert max(float(np.abs(b).max()) for b in s.slit_bias().values()) > 0
    a = slit_matrix(s.wavelength_nm, 5.0)
    np.testing.assert_allclose(a.sum(axis=1), 1.0, rtol=0, atol=1e-9)  # each slit function has unit area
