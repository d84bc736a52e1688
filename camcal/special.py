"""Special functions in numpy only: the normal CDF and the chi-square tail and its inverse.

``camcal calibrate`` imports no scipy (importing any scipy subpackage costs 0.1–0.3 s, more than
fitting a small session; docs/architecture.md, "Start-up"). The few special functions the
calibration stages need live here:

- :func:`ndtr`: the normal CDF through the Cephes rational approximations of erf and erfc (S. L.
  Moshier, *Methods and Programs for Mathematical Functions*, 1989; Cephes Math Library 2.9, ``ndtr.c``),
  the same coefficients and branches as ``scipy.special.ndtr`` (scipy's xsf ``cephes/ndtr.h``),
  vectorised over numpy arrays. Relative error ≤ ~1e-15 where the result is
  above ~1e-300, except the usual ~|x|²·ε of ``exp(−x²)`` far in the lower tail, as in scipy.
- :func:`gammainc_upper` (regularised upper incomplete gamma Q(a, x)): the power series of P for
  x < a + 1 and the Legendre continued fraction of Q (modified Lentz) otherwise (Press et al.,
  *Numerical Recipes*, 3rd ed., §6.2), prefactor ``exp(a ln x − x − lnΓ(a))`` with ``math.lgamma``.
- :func:`chi2_sf` and :func:`chi2_isf`: the chi-square survival function ``Q(ν/2, x/2)`` and its
  inverse, solved by a bracketed Newton iteration on ``ln Q`` with bisection fallback to 1e-14
  relative (matches ``scipy.special.chdtri(ν, p)`` = ``scipy.stats.chi2.isf(p, ν)`` to ≤ ~1e-13 relative, and
  ``scipy.special.chdtrc`` to ~1e-13 for ν ≤ 200; tests/test_numerics.py).
"""

from __future__ import annotations

import math

import numpy as np

_MAXLOG = 7.09782712893383996843e2
"""ln(DBL_MAX): below ``exp(−_MAXLOG)`` erfc underflows (Cephes MAXLOG)."""

# Cephes ndtr.c coefficients (erfc for 1 <= x < 8: P/Q; x >= 8: R/S; erf for |x| <= 1: T/U).
_P = (2.46196981473530512524e-10, 5.64189564831068821977e-1, 7.46321056442269912687e0,
      4.86371970985681366614e1, 1.96520832956077098242e2, 5.26445194995477358631e2,
      9.34528527171957607540e2, 1.02755188689515710272e3, 5.57535335369399327526e2)
_Q = (1.32281951154744992508e1, 8.67072140885989742329e1, 3.54937778887819891062e2,
      9.75708501743205489753e2, 1.82390916687909736289e3, 2.24633760818710981792e3,
      1.65666309194161350182e3, 5.57535340817727675546e2)
_R = (5.64189583547755073984e-1, 1.27536670759978104416e0, 5.01905042251180477414e0,
      6.16021097993053585195e0, 7.40974269950448939160e0, 2.97886665372100240670e0)
_S = (2.26052863220117276590e0, 9.39603524938001434673e0, 1.20489539808096656605e1,
      1.70814450747565897222e1, 9.60896809063285878198e0, 3.36907645100081516050e0)
_T = (9.60497373987051638749e0, 9.00260197203842689217e1, 2.23200534594684319226e3,
      7.00332514112805075473e3, 5.55923013010394962768e4)
_U = (3.35617141647503099647e1, 5.21357949780152679795e2, 4.59432382970980127987e3,
      2.26290000613890934246e4, 4.92673942608635921086e4)


def _pad9(coef: tuple[float, ...], leading_one: bool = False) -> tuple[float, ...]:
    """Coefficients for a 9-term Horner loop: leading zeros (exact: 0·w + 0 = 0, then 0·w + c = c)."""
    c = ((1.0,) if leading_one else ()) + coef
    return (0.0,) * (9 - len(c)) + c


# _NDTR_TABLE[i, k, b]: Horner coefficient i of the numerator (k = 0) or denominator (k = 1) of branch b
# (0: erf, |u| < 1, in u²; 1: erfc, 1 <= |u| < 8; 2: erfc, |u| >= 8); p1evl's implicit 1 made explicit.
_NDTR_TABLE = np.ascontiguousarray(np.array(
    [[_pad9(_T), _pad9(_U, True)], [_pad9(_P), _pad9(_Q, True)], [_pad9(_R), _pad9(_S, True)]]).transpose(2, 1, 0))


def ndtr(x: np.ndarray | float) -> np.ndarray:
    """Standard normal cumulative distribution Φ(x), vectorised.

    Cephes ``ndtr`` (as ``scipy.special.ndtr``): with u = x/√2, ``Φ = ½ + ½ erf(u)`` for |u| < 1,
    else ``½ erfc(|u|)`` (lower tail, full relative accuracy down to ~1e-308) and ``1 − ½ erfc(u)``
    for u ≥ 1; erf and erfc are the Cephes rational approximations (``x T(x²)/U(x²)``,
    ``exp(−x²) P(x)/Q(x)`` below 8, ``exp(−x²) R(x)/S(x)`` above; 0 where x² > ln DBL_MAX). Every element
    picks its branch's coefficients and one Horner loop evaluates them all (the same operations in
    the same order as Cephes, so the same values, at a third of the numpy calls of evaluating every
    branch). NaN gives NaN; ±inf give 1 and 0.

    Parameters
    ----------
    x : array_like, dimensionless (standard scores)

    Returns
    -------
    ndarray of float64 (0-d for a scalar input), probabilities in [0, 1].
    """
    x = np.asarray(x, dtype=np.float64)
    u = x * math.sqrt(0.5)
    z = np.abs(u)
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        zz = z * z
        inner = z < 1.0
        w = np.where(inner, zz, np.minimum(z, 64.0))  # beyond 64 the result underflows anyway
        coef = _NDTR_TABLE[:, :, (z >= 1.0).astype(np.intp) + (z >= 8.0)]  # (9, 2, *x.shape)
        ans = coef[0] * w + coef[1]
        for i in range(2, 9):
            ans = ans * w + coef[i]
        m = np.where(inner, u, np.where(zz > _MAXLOG, 0.0, np.exp(-zz)))
        t = 0.5 * ((m * ans[0]) / ans[1])
        out = np.where(inner, 0.5 + t, np.where(u > 0, 1.0 - t, t))
    return np.where(np.isnan(x), np.nan, out)


# ---- incomplete gamma and chi-square ---------------------------------------------------------------------------

_GAMMA_EPS = 1e-16
_GAMMA_MAXITER = 100000
_TINY = 1e-300


def _log_prefactor(a: float, x: float) -> float:
    """ln of ``x^a e^{−x} / Γ(a)``."""
    return a * math.log(x) - x - math.lgamma(a)


def _gamma_series_p(a: float, x: float) -> float:
    """Regularised lower incomplete gamma P(a, x) by its power series (converges fast for x < a + 1).

    ``P = x^a e^{−x}/Γ(a+1) · Σ_n x^n / ((a+1)…(a+n))`` (Numerical Recipes 3rd ed. eq. 6.2.5).
    """
    term = 1.0 / a
    total = term
    ap = a
    for _ in range(_GAMMA_MAXITER):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _GAMMA_EPS:
            break
    return total * math.exp(_log_prefactor(a, x))


def _gamma_cf_q(a: float, x: float) -> float:
    """Regularised upper incomplete gamma Q(a, x) by its continued fraction (x ≥ a + 1).

    Legendre's continued fraction evaluated by the modified Lentz method (Numerical Recipes 3rd ed.
    eq. 6.2.7 and §5.2).
    """
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _GAMMA_MAXITER):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        if abs(d) < _TINY:
            d = _TINY
        c = b + an / c
        if abs(c) < _TINY:
            c = _TINY
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _GAMMA_EPS:
            break
    return math.exp(_log_prefactor(a, x)) * h


def _gammainc_pair(a: float, x: float) -> tuple[float, float]:
    """(P, Q) at (a, x), the one not summed directly taken as 1 − the other."""
    if x < a + 1.0:
        lower = _gamma_series_p(a, x)
        return lower, 1.0 - lower
    upper = _gamma_cf_q(a, x)
    return 1.0 - upper, upper


def gammainc_upper(a: float, x: float) -> float:
    """Regularised upper incomplete gamma function ``Q(a, x) = Γ(a, x)/Γ(a)`` (scalar).

    Series of P for x < a + 1 (Q = 1 − P), Legendre continued fraction otherwise (Numerical Recipes
    3rd ed. §6.2); matches ``scipy.special.gammaincc(a, x)`` to ~1e-13 relative for a ≤ ~100 (the
    prefactor ``exp(a ln x − x − lnΓ(a))`` loses ~ε·x relative: ~2e-12 at a = 1000).

    Parameters
    ----------
    a : shape, > 0
    x : argument, ≥ 0

    Returns
    -------
    Q in [0, 1]; NaN for a ≤ 0, x < 0 or NaN input.
    """
    a, x = float(a), float(x)
    if not (a > 0.0) or not (x >= 0.0):
        return math.nan
    if x == 0.0:
        return 1.0
    if math.isinf(x):
        return 0.0
    return _gammainc_pair(a, x)[1]


def chi2_sf(x: float, dof: float) -> float:
    """Chi-square survival function ``P(X > x) = Q(ν/2, x/2)`` for ν = ``dof`` degrees of freedom.

    Matches ``scipy.special.chdtrc(dof, x)`` (= ``scipy.stats.chi2.sf(x, dof)``). ``dof`` need not
    be an integer. NaN for dof ≤ 0 or NaN x.
    """
    x, dof = float(x), float(dof)
    if not (dof > 0) or math.isnan(x):
        return math.nan
    if x <= 0:
        return 1.0
    return gammainc_upper(0.5 * dof, 0.5 * x)


def chi2_isf(p: float, dof: float) -> float:
    """Inverse chi-square survival function: the x with ``P(X > x) = p`` for ν = ``dof``.

    What ``scipy.special.chdtri(dof, p)`` and ``scipy.stats.chi2.isf(p, dof)`` give. With a = ν/2
    and y = x/2 it solves ``ln Q(a, y) = ln p`` (p ≤ ½) or ``ln P(a, y) = ln(1 − p)`` (p > ½, where
    1 − p is exact and Q would lose it) by Newton steps in ln y
    (``d ln Q / d ln y = −y^a e^{−y} / (Γ(a) Q)``), kept inside a bracket that always holds the
    root, with a bisection (in ln y) whenever a Newton step leaves the bracket or does not halve it.
    The start is the median-ish ``y = max(a, 1)`` (upper) or the first series term
    ``(Γ(a+1)(1 − p))^{1/a}`` (lower); the bracket grows by factors of 2 from there. Stops at
    1e-14 relative in x (Press et al., *Numerical Recipes* 3rd ed. §6.2 and §9.4).

    Parameters
    ----------
    p : tail probability in [0, 1]
    dof : degrees of freedom, > 0 (real)

    Returns
    -------
    x ≥ 0 (``inf`` for p = 0, 0 for p = 1); NaN for p outside [0, 1] or dof ≤ 0.
    """
    p, dof = float(p), float(dof)
    if not (0.0 <= p <= 1.0) or not (dof > 0):
        return math.nan
    if p == 0.0:
        return math.inf
    if p == 1.0:
        return 0.0
    a = 0.5 * dof
    upper = p <= 0.5
    target = p if upper else 1.0 - p  # exact for p > 1/2 (Sterbenz)
    log_target = math.log(target)
    sign = -1.0 if upper else 1.0  # the solved function rises (lower, P) or falls (upper, Q) with y

    def value(y: float) -> float:
        lower_y, upper_y = _gammainc_pair(a, y)
        return upper_y if upper else lower_y

    if upper:
        t = math.log(max(a, 1.0))
    else:
        t = min((log_target + math.lgamma(a + 1.0)) / a, math.log(max(a, 1.0)))
        t = max(t, math.log(1e-300))
    # bracket [t_lo, t_hi] in t = ln y: f(t) = sign·(g − target) < 0 at t_lo, > 0 at t_hi
    t_lo = t_hi = t
    f = sign * (value(math.exp(t)) - target)
    step = math.log(2.0)
    while f < 0:  # root above: move the upper end up
        t_lo, t_hi = t_hi, t_hi + step
        if t_hi > 710.0:
            return math.inf
        f = sign * (value(math.exp(t_hi)) - target)
    if t_lo == t_hi:
        while f > 0:  # root below: move the lower end down
            t_hi, t_lo = t_lo, t_lo - step
            if t_lo < -745.0:
                return 0.0
            f = sign * (value(math.exp(t_lo)) - target)
    t = 0.5 * (t_lo + t_hi)
    for _ in range(200):
        y = math.exp(t)
        g = value(y)
        if g == target:
            break
        if sign * (g - target) < 0:
            t_lo = t
        else:
            t_hi = t
        t_new = math.nan
        if g > 0:
            # d ln g / d ln y = sign · y^a e^{−y} / (Γ(a) g)
            slope = sign * math.exp(a * math.log(y) - y - math.lgamma(a)) / g
            if slope != 0:
                t_new = t - (math.log(g) - log_target) / slope
        if not (t_lo < t_new < t_hi) or abs(t_new - t) > 0.5 * (t_hi - t_lo):
            t_new = 0.5 * (t_lo + t_hi)
        done = abs(t_new - t) <= 1e-14 or (t_hi - t_lo) <= 1e-14
        t = t_new
        if done:
            break
    return 2.0 * math.exp(t)
