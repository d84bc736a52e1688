"""Small optimisers in numpy only: Nelder–Mead, bounded nonlinear least squares, a weighted curve fit.

``camcal calibrate`` imports no scipy (importing ``scipy.optimize`` costs ~0.25–0.30 s at start-up,
more than the fits themselves on a small session; docs/architecture.md, "Start-up"). The
calibration stages fit a handful of parameters (a 4-parameter likelihood in the dark stage, the
optical centre of a flat, the three parameters of seed eq. 12, the two of the sRGB form), so small
dense implementations suffice:

- :func:`nelder_mead`: the downhill simplex of Nelder & Mead (*Comput. J.* 7, 308, 1965) with the
  standard coefficients (reflection 1, expansion 2, contraction ½, shrink ½), the initial simplex,
  ordering and stopping rule of ``scipy.optimize.minimize(method="Nelder-Mead")`` (no bounds, not
  adaptive): on the same function it takes the same steps and returns the same point.
- :func:`least_squares`: the Trust Region Reflective algorithm of Branch, Coleman & Li (*SIAM J. Sci.
  Comput.* 21, 1, 1999) for bound-constrained nonlinear least squares, as
  ``scipy.optimize.least_squares(method="trf", tr_solver="exact", loss="linear")`` implements it:
  Coleman–Li scaling of the variables near active bounds, the exact trust-region subproblem solved
  through an SVD with Moré's iteration on the Levenberg–Marquardt parameter (Moré, *Numerical
  Analysis*, LNM 630, 1978), a reflected step at a bound, forward-difference Jacobians with scipy's
  step rule, ``x_scale`` (array or ``"jac"``) and its ftol/xtol/gtol stopping tests. Meant for
  small problems (≤ ~10 parameters, ≤ ~10⁴ residuals; one dense SVD of the (m + n) × n Jacobian per
  iteration).
- :func:`curve_fit`: weighted least squares of a model y = f(x, *p) with bounds, and the covariance
  ``pinv(JᵀJ)`` of the weighted residuals at the solution (``absolute_sigma=True`` semantics of
  ``scipy.optimize.curve_fit``, via the SVD with its cut-off ``ε · max(m, n) · s₀``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

EPS = float(np.finfo(float).eps)
"""Machine epsilon of float64."""


class MaxFunctionCalls(Exception):
    """Raised inside :func:`nelder_mead` when the evaluation budget is spent (caught there)."""


@dataclass(frozen=True)
class MinimizeResult:
    """Result of :func:`nelder_mead`.

    Attributes
    ----------
    x : best vertex found
    fun : objective at ``x``
    nit : iterations
    nfev : objective evaluations
    success : stopped on the xatol/fatol test (not on the iteration or evaluation budget)
    status : 0 converged, 1 evaluation budget spent, 2 iteration budget spent
    message : what stopped it
    """

    x: np.ndarray
    fun: float
    nit: int
    nfev: int
    success: bool
    status: int
    message: str


def nelder_mead(
    f: Callable[[np.ndarray], float],
    x0: Sequence[float] | np.ndarray,
    *,
    xatol: float = 1e-4,
    fatol: float = 1e-4,
    maxiter: int | None = None,
    maxfev: int | None = None,
) -> MinimizeResult:
    """Minimise ``f`` by the Nelder–Mead downhill simplex (no bounds).

    Algorithm and constants as ``scipy.optimize.minimize(f, x0, method="Nelder-Mead",
    options={"xatol", "fatol", "maxiter", "maxfev"})`` (scipy ``_minimize_neldermead``, not adaptive):
    initial simplex x0 plus, per coordinate k, x0 with x0[k] scaled by 1.05 (or set to 0.00025 where
    it is 0); reflection ρ = 1, expansion χ = 2, contraction ψ = ½, shrink σ = ½ (Nelder & Mead 1965;
    Lagarias et al., *SIAM J. Optim.* 9, 112, 1998); stop when every vertex is within ``xatol`` of the
    best in every coordinate *and* every function value within ``fatol`` of the best. Default budgets
    200·n iterations and evaluations when neither is given.

    Parameters
    ----------
    f : objective, called with a copy of a 1-D float array, returning a scalar
    x0 : start, shape (n,)
    xatol, fatol : absolute tolerances on the simplex size (units of x) and on f (units of f)
    maxiter, maxfev : iteration and evaluation budgets

    Returns
    -------
    MinimizeResult
    """
    x0 = np.atleast_1d(np.asarray(x0)).flatten()
    dtype = x0.dtype if np.issubdtype(x0.dtype, np.inexact) else np.float64
    x0 = np.asarray(x0, dtype=dtype)
    rho, chi, psi, sigma = 1.0, 2.0, 0.5, 0.5
    n = len(x0)
    sim = np.empty((n + 1, n), dtype=x0.dtype)
    sim[0] = x0
    for k in range(n):
        y = np.array(x0, copy=True)
        y[k] = (1 + 0.05) * y[k] if y[k] != 0 else 0.00025
        sim[k + 1] = y
    if maxiter is None and maxfev is None:
        maxiter = maxfev = n * 200
    elif maxiter is None:
        maxiter = n * 200 if maxfev == np.inf else np.inf
    elif maxfev is None:
        maxfev = n * 200 if maxiter == np.inf else np.inf

    ncalls = [0]

    def func(x: np.ndarray) -> float:
        if ncalls[0] >= maxfev:
            raise MaxFunctionCalls
        ncalls[0] += 1
        fx = f(np.copy(x))
        return fx if np.isscalar(fx) else np.asarray(fx).item()

    fsim = np.full((n + 1,), np.inf, dtype=float)
    try:
        for k in range(n + 1):
            fsim[k] = func(sim[k])
    except MaxFunctionCalls:
        pass
    ind = np.argsort(fsim)
    sim, fsim = np.take(sim, ind, 0), np.take(fsim, ind, 0)
    iterations = 1
    while ncalls[0] < maxfev and iterations < maxiter:
        try:
            if (np.max(np.ravel(np.abs(sim[1:] - sim[0]))) <= xatol
                    and np.max(np.abs(fsim[0] - fsim[1:])) <= fatol):
                break
            xbar = np.add.reduce(sim[:-1], 0) / n
            xr = (1 + rho) * xbar - rho * sim[-1]
            fxr = func(xr)
            shrink = False
            if fxr < fsim[0]:
                xe = (1 + rho * chi) * xbar - rho * chi * sim[-1]
                fxe = func(xe)
                if fxe < fxr:
                    sim[-1], fsim[-1] = xe, fxe
                else:
                    sim[-1], fsim[-1] = xr, fxr
            elif fxr < fsim[-2]:
                sim[-1], fsim[-1] = xr, fxr
            elif fxr < fsim[-1]:  # outside contraction
                xc = (1 + psi * rho) * xbar - psi * rho * sim[-1]
                fxc = func(xc)
                if fxc <= fxr:
                    sim[-1], fsim[-1] = xc, fxc
                else:
                    shrink = True
            else:  # inside contraction
                xcc = (1 - psi) * xbar + psi * sim[-1]
                fxcc = func(xcc)
                if fxcc < fsim[-1]:
                    sim[-1], fsim[-1] = xcc, fxcc
                else:
                    shrink = True
            if shrink:
                for j in range(1, n + 1):
                    sim[j] = sim[0] + sigma * (sim[j] - sim[0])
                    fsim[j] = func(sim[j])
            iterations += 1
        except MaxFunctionCalls:
            pass
        ind = np.argsort(fsim)
        sim, fsim = np.take(sim, ind, 0), np.take(fsim, ind, 0)
    if ncalls[0] >= maxfev:
        status, message = 1, "Maximum number of function evaluations has been exceeded."
    elif iterations >= maxiter:
        status, message = 2, "Maximum number of iterations has been exceeded."
    else:
        status, message = 0, "Optimization terminated successfully."
    return MinimizeResult(x=sim[0], fun=float(np.min(fsim)), nit=iterations, nfev=ncalls[0],
                          success=status == 0, status=status, message=message)


# ---- bounded nonlinear least squares (Trust Region Reflective) -------------------------------------------------


@dataclass(frozen=True)
class LeastSquaresResult:
    """Result of :func:`least_squares`.

    Attributes
    ----------
    x : solution, shape (n,)
    fun : residuals at ``x``, shape (m,)
    jac : forward-difference Jacobian of the residuals at ``x``, shape (m, n)
    cost : ½ Σ fun²
    grad : jacᵀ fun
    optimality : ‖v · grad‖∞ with the Coleman–Li scaling v (first-order optimality with bounds)
    active_mask : −1 / 0 / 1 per variable: at its lower bound, free, at its upper bound
    nfev : residual evaluations by the algorithm (those of the finite differences not counted)
    njev : Jacobian evaluations
    status : 0 evaluation budget spent, 1 gtol, 2 ftol, 3 xtol, 4 ftol and xtol satisfied
    success : ``status > 0``
    message : what stopped it
    """

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    cost: float
    grad: np.ndarray
    optimality: float
    active_mask: np.ndarray
    nfev: int
    njev: int
    status: int
    success: bool
    message: str


_MESSAGES = {
    0: "The maximum number of function evaluations is exceeded.",
    1: "`gtol` termination condition is satisfied.",
    2: "`ftol` termination condition is satisfied.",
    3: "`xtol` termination condition is satisfied.",
    4: "Both `ftol` and `xtol` termination conditions are satisfied.",
}


def _norm(v: np.ndarray) -> float:
    """Euclidean norm."""
    return float(np.linalg.norm(v))


def _in_bounds(x: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> bool:
    """lb ≤ x ≤ ub everywhere."""
    return bool(np.all((x >= lb) & (x <= ub)))


def _active_constraints(x: np.ndarray, lb: np.ndarray, ub: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """−1 / 0 / 1 per variable: within ``rtol`` (relative, at least absolute) of its lower / no / upper bound."""
    active = np.zeros_like(x, dtype=int)
    if rtol == 0:
        active[x <= lb] = -1
        active[x >= ub] = 1
        return active
    lower_dist, upper_dist = x - lb, ub - x
    lower_active = np.isfinite(lb) & (lower_dist <= np.minimum(upper_dist, rtol * np.maximum(1, np.abs(lb))))
    active[lower_active] = -1
    upper_active = np.isfinite(ub) & (upper_dist <= np.minimum(lower_dist, rtol * np.maximum(1, np.abs(ub))))
    active[upper_active] = 1
    return active


def _strictly_feasible(x: np.ndarray, lb: np.ndarray, ub: np.ndarray, rstep: float = 1e-10) -> np.ndarray:
    """Move variables on (or within ``rstep`` of) a bound just inside it."""
    x_new = x.copy()
    active = _active_constraints(x, lb, ub, rstep)
    lower, upper = active == -1, active == 1
    if rstep == 0:
        x_new[lower] = np.nextafter(lb[lower], ub[lower])
        x_new[upper] = np.nextafter(ub[upper], lb[upper])
    else:
        x_new[lower] = lb[lower] + rstep * np.maximum(1, np.abs(lb[lower]))
        x_new[upper] = ub[upper] - rstep * np.maximum(1, np.abs(ub[upper]))
    tight = (x_new < lb) | (x_new > ub)
    x_new[tight] = 0.5 * (lb[tight] + ub[tight])
    return x_new


def _step_to_bound(x: np.ndarray, s: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> tuple[float, np.ndarray]:
    """Largest t with x + t·s feasible, and which variables reach their bound there (sign of s)."""
    nz = np.nonzero(s)
    steps = np.full_like(x, np.inf)
    with np.errstate(over="ignore"):
        steps[nz] = np.maximum((lb - x)[nz] / s[nz], (ub - x)[nz] / s[nz])
    t = float(np.min(steps))
    return t, np.equal(steps, t) * np.sign(s).astype(int)


def _intersect_trust_region(x: np.ndarray, s: np.ndarray, delta: float) -> tuple[float, float]:
    """The two t with ‖x + t s‖ = Δ (x inside the region), smaller first (stable quadratic roots)."""
    a = float(np.dot(s, s))
    if a == 0:
        raise ValueError("`s` is zero.")
    b = float(np.dot(x, s))
    c = float(np.dot(x, x)) - delta**2
    if c > 0:
        raise ValueError("`x` is not within the trust region.")
    d = math.sqrt(b * b - a * c)
    q = -(b + math.copysign(d, b))
    t1, t2 = q / a, c / q
    return (t1, t2) if t1 < t2 else (t2, t1)


def _solve_trust_region(n: int, m: int, uf: np.ndarray, s: np.ndarray, v: np.ndarray, delta: float,
                        initial_alpha: float | None = None, rtol: float = 0.01,
                        max_iter: int = 10) -> tuple[np.ndarray, float]:
    """min ‖J p + f‖ subject to ‖p‖ ≤ Δ from the SVD J = U diag(s) Vᵀ (uf = Uᵀ f).

    Gauss–Newton step if it fits, else the Levenberg–Marquardt parameter α solving ‖p(α)‖ = Δ by
    Moré's (1978) safeguarded Newton iteration on φ(α) = ‖p(α)‖ − Δ, to ``rtol`` relative.
    """
    suf = s * uf
    full_rank = bool(s[-1] > EPS * m * s[0]) if m >= n else False
    if full_rank:
        p = -v.dot(uf / s)
        if _norm(p) <= delta:
            return p, 0.0

    def phi_and_derivative(alpha: float) -> tuple[float, float]:
        denom = s**2 + alpha
        p_norm = _norm(suf / denom)
        return p_norm - delta, -float(np.sum(suf**2 / denom**3)) / p_norm

    alpha_upper = _norm(suf) / delta
    if full_rank:
        phi, phi_prime = phi_and_derivative(0.0)
        alpha_lower = -phi / phi_prime
    else:
        alpha_lower = 0.0
    if initial_alpha is None or not full_rank and initial_alpha == 0:
        alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
    else:
        alpha = initial_alpha
    for _ in range(max_iter):
        if alpha < alpha_lower or alpha > alpha_upper:
            alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
        phi, phi_prime = phi_and_derivative(alpha)
        if phi < 0:
            alpha_upper = alpha
        ratio = phi / phi_prime
        alpha_lower = max(alpha_lower, alpha - ratio)
        alpha -= (phi + delta) * ratio / delta
        if abs(phi) < rtol * delta:
            break
    p = -v.dot(suf / (s**2 + alpha))
    p *= delta / _norm(p)  # exactly on the trust-region boundary
    return p, alpha


def _quadratic_1d(jh: np.ndarray, g: np.ndarray, s: np.ndarray, diag: np.ndarray,
                  s0: np.ndarray | None = None) -> tuple[float, float, float]:
    """Coefficients a, b, c of the model along s0 + t·s: a t² + b t + c."""
    v = jh.dot(s)
    a = 0.5 * (float(np.dot(v, v)) + float(np.dot(s * diag, s)))
    b = float(np.dot(g, s))
    c = 0.0
    if s0 is not None:
        u = jh.dot(s0)
        b += float(np.dot(u, v)) + float(np.dot(s0 * diag, s))
        c = 0.5 * float(np.dot(u, u)) + float(np.dot(g, s0)) + 0.5 * float(np.dot(s0 * diag, s0))
    return a, b, c


def _minimise_quadratic_1d(a: float, b: float, lo: float, hi: float, c: float = 0.0) -> tuple[float, float]:
    """Minimum of a t² + b t + c over [lo, hi]."""
    t = [lo, hi]
    if a != 0:
        extremum = -0.5 * b / a
        if lo < extremum < hi:
            t.append(extremum)
    ta = np.asarray(t)
    y = ta * (a * ta + b) + c
    i = int(np.argmin(y))
    return float(ta[i]), float(y[i])


def _evaluate_quadratic(jh: np.ndarray, g: np.ndarray, s: np.ndarray, diag: np.ndarray) -> float:
    """Model value ½ sᵀ(JᵀJ + diag)s + gᵀs."""
    js = jh.dot(s)
    return 0.5 * (float(np.dot(js, js)) + float(np.dot(s * diag, s))) + float(np.dot(s, g))


def _select_step(x: np.ndarray, jh: np.ndarray, diag_h: np.ndarray, g_h: np.ndarray, p: np.ndarray,
                 p_h: np.ndarray, d: np.ndarray, delta: float, lb: np.ndarray, ub: np.ndarray,
                 theta: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The best of the trust-region step (cut back at a bound), its reflection and the scaled gradient step.

    Branch, Coleman & Li (1999) §3; as scipy ``_lsq.trf.select_step``.
    """
    if _in_bounds(x + p, lb, ub):
        return p, p_h, -_evaluate_quadratic(jh, g_h, p_h, diag_h)
    p_stride, hits = _step_to_bound(x, p, lb, ub)
    r_h = np.copy(p_h)
    r_h[hits.astype(bool)] *= -1
    r = d * r_h
    p = p * p_stride
    p_h = p_h * p_stride
    x_on_bound = x + p
    _, to_tr = _intersect_trust_region(p_h, r_h, delta)
    to_bound, _ = _step_to_bound(x_on_bound, r, lb, ub)
    r_stride = min(to_bound, to_tr)
    if r_stride > 0:
        r_stride_l = (1 - theta) * p_stride / r_stride
        r_stride_u = theta * to_bound if r_stride == to_bound else to_tr
    else:
        r_stride_l, r_stride_u = 0.0, -1.0
    if r_stride_l <= r_stride_u:
        a, b, c = _quadratic_1d(jh, g_h, r_h, diag_h, s0=p_h)
        r_stride, r_value = _minimise_quadratic_1d(a, b, r_stride_l, r_stride_u, c=c)
        r_h = r_h * r_stride + p_h
        r = r_h * d
    else:
        r_value = np.inf
    p = p * theta
    p_h = p_h * theta
    p_value = _evaluate_quadratic(jh, g_h, p_h, diag_h)
    ag_h = -g_h
    ag = d * ag_h
    to_tr = delta / _norm(ag_h)
    to_bound, _ = _step_to_bound(x, ag, lb, ub)
    ag_stride = theta * to_bound if to_bound < to_tr else to_tr
    a, b, _ = _quadratic_1d(jh, g_h, ag_h, diag_h)
    ag_stride, ag_value = _minimise_quadratic_1d(a, b, 0.0, ag_stride)
    ag_h = ag_h * ag_stride
    ag = ag * ag_stride
    if p_value < r_value and p_value < ag_value:
        return p, p_h, -p_value
    if r_value < p_value and r_value < ag_value:
        return r, r_h, -r_value
    return ag, ag_h, -ag_value


def _cl_scaling(x: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coleman–Li scaling vector v (distance to the bound the gradient points to, else 1) and dv/dx."""
    v = np.ones_like(x)
    dv = np.zeros_like(x)
    mask = (g < 0) & np.isfinite(ub)
    v[mask] = ub[mask] - x[mask]
    dv[mask] = -1
    mask = (g > 0) & np.isfinite(lb)
    v[mask] = x[mask] - lb[mask]
    dv[mask] = 1
    return v, dv


def _jac_scale(jac: np.ndarray, scale_inv_old: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``x_scale="jac"``: inverse column norms of J (never decreasing over the iterations)."""
    scale_inv = np.sum(jac**2, axis=0) ** 0.5
    if scale_inv_old is None:
        scale_inv[scale_inv == 0] = 1
    else:
        scale_inv = np.maximum(scale_inv, scale_inv_old)
    return 1 / scale_inv, scale_inv


def forward_difference_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f0: np.ndarray,
                                lb: np.ndarray, ub: np.ndarray, rel_step: float | None = None) -> np.ndarray:
    """Forward-difference Jacobian (m, n) of ``fun`` at ``x`` with ``f0 = fun(x)``, steps kept inside the bounds.

    Step rule of ``scipy.optimize.approx_derivative(method="2-point")``: h = √ε · sign(x) · max(1, |x|)
    by default, ``rel_step · sign(x) · |x|`` when given (falling back to the default where that
    step vanishes; sign(0) = +1); a step that would leave the bounds is taken backwards when that
    fits, else to the farther bound. The derivative uses the step actually represented,
    ``(x + h) − x`` (Nocedal & Wright, *Numerical Optimization*, 2nd ed. §8.1).
    """
    sign_x = (x >= 0).astype(float) * 2 - 1
    default = EPS**0.5 * sign_x * np.maximum(1.0, np.abs(x))
    if rel_step is None:
        h = default
    else:
        h = rel_step * sign_x * np.abs(x)
        h = np.where(((x + h) - x) == 0, default, h)
    if not np.all((lb == -np.inf) & (ub == np.inf)):
        lower_dist, upper_dist = x - lb, ub - x
        xh = x + h
        violated = (xh < lb) | (xh > ub)
        fitting = np.abs(h) <= np.maximum(lower_dist, upper_dist)
        h = h.copy()
        h[violated & fitting] *= -1
        forward = (upper_dist >= lower_dist) & ~fitting
        h[forward] = upper_dist[forward]
        backward = (upper_dist < lower_dist) & ~fitting
        h[backward] = -lower_dist[backward]
    jt = np.empty((x.size, f0.size))
    for i in range(x.size):
        x1 = np.copy(x)
        x1[i] = x[i] + h[i]
        dx = (x[i] + h[i]) - x[i]
        jt[i] = (np.atleast_1d(fun(x1)) - f0) / dx
    return jt.T


def _prepare_bounds(bounds: tuple, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(lb, ub) as float arrays of shape (n,) (scalars repeated)."""
    lb, ub = (np.asarray(b, dtype=float) for b in bounds)
    lb = np.resize(lb, n) if lb.ndim == 0 else lb
    ub = np.resize(ub, n) if ub.ndim == 0 else ub
    return lb, ub


def least_squares(
    fun: Callable[[np.ndarray], np.ndarray],
    x0: Sequence[float] | np.ndarray,
    *,
    bounds: tuple = (-np.inf, np.inf),
    x_scale: str | float | Sequence[float] | np.ndarray | None = None,
    diff_step: float | None = None,
    xtol: float = 1e-8,
    ftol: float = 1e-8,
    gtol: float = 1e-8,
    max_nfev: int | None = None,
) -> LeastSquaresResult:
    """Minimise ½ Σ fun(x)² subject to lb ≤ x ≤ ub by the Trust Region Reflective method.

    Branch, Coleman & Li (1999), "A subspace, interior, and conjugate gradient method for large-scale
    bound-constrained minimization problems", *SIAM J. Sci. Comput.* 21, 1–23, in the dense form of
    ``scipy.optimize.least_squares(method="trf", tr_solver="exact")`` (same step selection, radius
    update, scaling and stopping rules; same optimum, iterates equal to rounding of the SVD):

    - the variables are scaled by ``x_scale`` (``"jac"``: inverse Jacobian column norms, updated
      upwards) and by the Coleman–Li vector v (distance to the bound the gradient points to);
    - the trust-region subproblem of the augmented system [J·d; diag(g·dv·scale)^½] is solved
      exactly through its SVD (Moré 1978); a step leaving the feasible box is cut at the bound and
      compared with its reflection and with a scaled gradient step, all kept a factor
      θ = max(0.995, 1 − ‖g_h‖∞) inside;
    - the radius is quartered when the actual/predicted reduction ratio is below ¼ and doubled
      above ¾ when the step reached the boundary;
    - stop when ‖v·g‖∞ < gtol (1), the cost falls by less than ftol·cost at a good step (2), the
      step is shorter than xtol·(xtol + ‖x‖) (3), both 2 and 3 (4), or after ``max_nfev``
      evaluations (0; default 100·n).

    The Jacobian is :func:`forward_difference_jacobian` (``diff_step`` its relative step).

    Parameters
    ----------
    fun : residuals r(x), shape (m,), for x of shape (n,)
    x0 : start, inside the bounds (moved strictly inside by 1e-10 relative)
    bounds : (lb, ub), scalars or arrays of shape (n,); ±inf for none
    x_scale : characteristic scale of each variable, or ``"jac"``; default 1
    diff_step : relative finite-difference step; default √ε·max(1, |x|) absolute
    xtol, ftol, gtol : stopping tolerances (see above)
    max_nfev : evaluation budget of the algorithm

    Returns
    -------
    LeastSquaresResult

    Raises
    ------
    ValueError
        Inconsistent shapes, lb ≥ ub, x0 outside the bounds, residuals not finite at x0.
    """
    x0 = np.atleast_1d(np.asarray(x0, dtype=float)).copy()
    if x0.ndim > 1:
        raise ValueError("`x0` must have at most 1 dimension.")
    n = x0.size
    lb, ub = _prepare_bounds(bounds, n)
    if lb.shape != x0.shape or ub.shape != x0.shape:
        raise ValueError("Inconsistent shapes between bounds and `x0`.")
    if np.any(lb >= ub):
        raise ValueError("Each lower bound must be strictly less than each upper bound.")
    if not _in_bounds(x0, lb, ub):
        raise ValueError("Initial guess is outside of provided bounds")
    if x_scale is None:
        x_scale = 1.0
    jac_scale = isinstance(x_scale, str)
    if jac_scale and x_scale != "jac":
        raise ValueError("`x_scale` must be 'jac' or array_like with positive numbers.")
    if not jac_scale:
        x_scale = np.asarray(x_scale, dtype=float)
        if not (np.all(np.isfinite(x_scale)) and np.all(x_scale > 0)):
            raise ValueError("`x_scale` must be 'jac' or array_like with positive numbers.")
        x_scale = np.resize(x_scale, x0.shape) if x_scale.ndim == 0 else x_scale
        if x_scale.shape != x0.shape:
            raise ValueError("Inconsistent shapes between `x_scale` and `x0`.")
    if ftol < EPS and xtol < EPS and gtol < EPS:
        raise ValueError(f"At least one of the tolerances must be higher than machine epsilon ({EPS:.2e}).")
    if max_nfev is not None and max_nfev <= 0:
        raise ValueError("`max_nfev` must be None or positive integer.")

    def fun1(x: np.ndarray) -> np.ndarray:
        return np.atleast_1d(np.asarray(fun(x), dtype=float))

    def jac(x: np.ndarray, f: np.ndarray) -> np.ndarray:
        return forward_difference_jacobian(fun1, x, f, lb, ub, diff_step)

    x = _strictly_feasible(x0, lb, ub)
    f = fun1(x)
    if f.ndim != 1:
        raise ValueError("`fun` must return at most 1-d array_like.")
    if not np.all(np.isfinite(f)):
        raise ValueError("Residuals are not finite in the initial point.")
    m = f.size
    J = jac(x, f)
    nfev = njev = 1
    cost = 0.5 * float(np.dot(f, f))
    g = J.T.dot(f)
    if jac_scale:
        scale, scale_inv = _jac_scale(J)
    else:
        scale, scale_inv = x_scale, 1 / x_scale
    v, dv = _cl_scaling(x, g, lb, ub)
    v[dv != 0] *= scale_inv[dv != 0]
    delta = _norm(x * scale_inv / v**0.5)
    if delta == 0:
        delta = 1.0
    f_aug = np.zeros(m + n)
    j_aug = np.empty((m + n, n))
    if max_nfev is None:
        max_nfev = n * 100
    alpha = 0.0
    status = None
    while True:
        v, dv = _cl_scaling(x, g, lb, ub)
        g_norm = float(np.linalg.norm(g * v, ord=np.inf))
        if g_norm < gtol:
            status = 1
        if status is not None or nfev == max_nfev:
            break
        v[dv != 0] *= scale_inv[dv != 0]
        d = v**0.5 * scale
        diag_h = g * dv * scale
        g_h = d * g
        f_aug[:m] = f
        j_aug[:m] = J * d
        jh = j_aug[:m]
        j_aug[m:] = np.diag(diag_h**0.5)
        u_, s_, vt = np.linalg.svd(j_aug, full_matrices=False)
        v_ = vt.T
        uf = u_.T.dot(f_aug)
        theta = max(0.995, 1 - g_norm)
        actual_reduction = -1.0
        while actual_reduction <= 0 and nfev < max_nfev:
            p_h, alpha = _solve_trust_region(n, m, uf, s_, v_, delta, initial_alpha=alpha)
            p = d * p_h
            step, step_h, predicted_reduction = _select_step(x, jh, diag_h, g_h, p, p_h, d, delta, lb, ub, theta)
            x_new = _strictly_feasible(x + step, lb, ub, rstep=0)
            f_new = fun1(x_new)
            nfev += 1
            step_h_norm = _norm(step_h)
            if not np.all(np.isfinite(f_new)):
                delta = 0.25 * step_h_norm
                continue
            cost_new = 0.5 * float(np.dot(f_new, f_new))
            actual_reduction = cost - cost_new
            # radius update (ratio of actual to predicted reduction)
            if predicted_reduction > 0:
                ratio = actual_reduction / predicted_reduction
            elif predicted_reduction == actual_reduction == 0:
                ratio = 1.0
            else:
                ratio = 0.0
            delta_new = delta
            if ratio < 0.25:
                delta_new = 0.25 * step_h_norm
            elif ratio > 0.75 and step_h_norm > 0.95 * delta:
                delta_new = 2.0 * delta
            step_norm = _norm(step)
            ftol_ok = actual_reduction < ftol * cost and ratio > 0.25
            xtol_ok = step_norm < xtol * (xtol + _norm(x))
            if ftol_ok or xtol_ok:
                status = 4 if ftol_ok and xtol_ok else (2 if ftol_ok else 3)
                break
            alpha *= delta / delta_new
            delta = delta_new
        if actual_reduction > 0:
            x, f, cost = x_new, f_new, cost_new
            J = jac(x, f)
            njev += 1
            g = J.T.dot(f)
            if jac_scale:
                scale, scale_inv = _jac_scale(J, scale_inv)
    if status is None:
        status = 0
    return LeastSquaresResult(
        x=x, fun=f, jac=J, cost=cost, grad=g, optimality=g_norm, active_mask=_active_constraints(x, lb, ub, xtol),
        nfev=nfev, njev=njev, status=status, success=status > 0, message=_MESSAGES[status])


def covariance_from_jacobian(jac: np.ndarray) -> np.ndarray:
    """``pinv(JᵀJ)`` through the SVD of J, singular values ≤ ε·max(m, n)·s₀ dropped (as ``curve_fit``).

    Returns an (n, n) array of ``inf`` when J or the result is not finite (covariance not estimable).
    """
    if not np.all(np.isfinite(jac)):
        return np.full((jac.shape[1], jac.shape[1]), np.inf)
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    threshold = EPS * max(jac.shape) * s[0]
    s = s[s > threshold]
    vt = vt[: s.size]
    pcov = np.dot(vt.T / s**2, vt)
    if np.isnan(pcov).any():
        pcov = np.full((jac.shape[1], jac.shape[1]), np.inf)
    return pcov


def curve_fit(
    f: Callable[..., np.ndarray],
    xdata: np.ndarray,
    ydata: np.ndarray,
    p0: Sequence[float] | np.ndarray,
    *,
    sigma: np.ndarray | None = None,
    bounds: tuple = (-np.inf, np.inf),
    x_scale: str | float | Sequence[float] | np.ndarray | None = None,
    diff_step: float | None = None,
    xtol: float = 1e-8,
    ftol: float = 1e-8,
    gtol: float = 1e-8,
    max_nfev: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least-squares fit of ``y = f(x, *p)``: parameters and their covariance (absolute sigma).

    What ``scipy.optimize.curve_fit(f, xdata, ydata, p0, sigma=sigma, absolute_sigma=True,
    bounds=bounds, method="trf", ...)`` returns: :func:`least_squares` of the residuals
    ``(f(x, *p) − y) / σ``, then ``pcov = pinv(JᵀJ)`` of those weighted residuals at the solution
    (:func:`covariance_from_jacobian`), not scaled by the reduced χ².

    Parameters
    ----------
    f : model, called as ``f(xdata, *p)``
    xdata, ydata : data (finite)
    p0 : start, shape (n,)
    sigma : standard deviations of ``ydata`` (same units), shape (m,) or scalar; default 1
    bounds, x_scale, diff_step, xtol, ftol, gtol, max_nfev : as :func:`least_squares`

    Returns
    -------
    popt : shape (n,)
    pcov : shape (n, n), ``inf`` everywhere when not estimable

    Raises
    ------
    ValueError
        Non-finite data, residuals not finite at p0, p0 outside the bounds.
    RuntimeError
        The fit stopped on its evaluation budget.
    """
    ydata = np.asarray_chkfinite(ydata, float)
    xdata = np.asarray_chkfinite(xdata, float)
    if ydata.size == 0:
        raise ValueError("`ydata` must not be empty!")
    transform = 1.0 if sigma is None else 1.0 / np.asarray(sigma, float)

    def resid(p: np.ndarray) -> np.ndarray:
        return transform * (f(xdata, *p) - ydata)

    res = least_squares(resid, np.atleast_1d(np.asarray(p0, float)), bounds=bounds, x_scale=x_scale,
                        diff_step=diff_step, xtol=xtol, ftol=ftol, gtol=gtol, max_nfev=max_nfev)
    if not res.success:
        raise RuntimeError("Optimal parameters not found: " + res.message)
    return res.x, covariance_from_jacobian(res.jac)
