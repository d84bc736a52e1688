"""Cubic interpolating splines in numpy alone (no scipy), for the calibrate path.

``camcal calibrate`` must not import scipy: importing any scipy subpackage costs >= 0.1 s of start-up
(``scipy.interpolate`` about 0.3 s on the project machine), more than the fits of a small session. The
spectral stage needs only small cubic splines (a few hundred knots at most), so they are written here:
:func:`cubic_spline` builds the C² piecewise cubic through the knots and returns a
:class:`PiecewiseCubic` that evaluates the value and the first, second and third derivatives.

Algorithm (the one of ``scipy.interpolate.CubicSpline``, which it matches to rounding): the unknowns
are the slopes s_i at the knots. Continuity of the second derivative at each interior knot gives

    Δ_i s_{i-1} + 2 (Δ_{i-1} + Δ_i) s_i + Δ_{i-1} s_{i+1} = 3 (Δ_i m_{i-1} + Δ_{i-1} m_i),

with Δ_i = x_{i+1} − x_i and m_i = (y_{i+1} − y_i) / Δ_i (de Boor 2001, ch. IV, cubic spline
interpolation in terms of the slopes); two end conditions close the tridiagonal system:

- ``"natural"``: zero second derivative at both ends (de Boor 2001, ch. IV, the "natural" end
  condition), the rows 2 Δ_0 s_0 + Δ_0 s_1 = 3 (y_1 − y_0) and its mirror at the last knot;
- ``"not-a-knot"``: the third derivative is continuous across x_1 and x_{n-2}, so the first two and
  the last two pieces are one cubic each (de Boor 2001, ch. IV, the not-a-knot end condition; scipy's
  default). Each such row is the condition with s_2 (s_{n-3}) eliminated through the neighbouring
  interior row, exactly as scipy writes it.

Special cases, as in scipy: with 2 knots the spline is the straight line (either condition); with 3
knots and ``"not-a-knot"`` it is the parabola through the points (a 3×3 system).

The tridiagonal system is solved by Gaussian elimination without pivoting (the Thomas algorithm;
Golub & Van Loan 2013, §4.3), vectorised over the columns of ``y`` (scipy uses LAPACK's pivoted band
solver). Without pivoting is safe here: the interior rows are strictly diagonally dominant, so with
either end condition every pivot is positive and, after the first row, each ratio upper/pivot that the
back substitution multiplies by is below 1 in magnitude. ``tests/test_spline.py`` checks it: with
neighbouring knot spacings differing by up to 10^4 the slopes are right to 3e-14 of exact rational
arithmetic, as scipy's (2.5e-14). Each piece is then
the cubic Hermite polynomial of its end values and slopes (as ``scipy.interpolate.CubicHermiteSpline``),
stored like ``scipy.interpolate.PPoly``: coefficients of (x − x_i)³, (x − x_i)², (x − x_i), 1.

Cost: O(n) Python-level steps of O(m) numpy work for m curves; the (n, n) cardinal basis
``cubic_spline(x, np.eye(n), "natural")`` takes ~1 ms for n = 59 and ~10 ms for n = 291.

References
----------
de Boor, C. (2001). *A Practical Guide to Splines*, revised ed. Springer, ch. IV.
Golub, G. H., Van Loan, C. F. (2013). *Matrix Computations*, 4th ed. Johns Hopkins, §4.3 (banded
and tridiagonal systems).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

#: End conditions :func:`cubic_spline` knows.
BoundaryCondition = Literal["not-a-knot", "natural"]


@dataclass(frozen=True, eq=False)
class PiecewiseCubic:
    """A piecewise cubic on strictly increasing knots, evaluated like ``scipy.interpolate.PPoly``.

    Attributes
    ----------
    knots : (n,) strictly increasing break points, in the unit of the abscissa (e.g. nm).
    coefficients : (4, n - 1, ...) per piece i, the coefficients of (x − knots[i])³, ², ¹, ⁰
        (highest power first, scipy's ``PPoly.c`` layout); trailing axes are those of the values.
    extrapolate : True: outside [knots[0], knots[-1]] the end pieces continue; False: NaN there.
    """

    knots: np.ndarray
    coefficients: np.ndarray
    extrapolate: bool = True

    def __call__(self, x: np.ndarray | float, nu: int = 0) -> np.ndarray:
        """Value (``nu`` = 0) or ``nu``-th derivative at ``x``.

        Parameters
        ----------
        x : points, any shape, in the unit of the knots.
        nu : order of the derivative, 0..3 (higher orders are 0); the result's unit is the values'
            unit per (knot unit)^nu.

        Returns
        -------
        np.ndarray
            Shape ``np.shape(x) + values.shape[1:]`` (like scipy's ``CubicSpline.__call__``). A point
            on a knot takes the piece to its right (the last knot the last piece). NaN at NaN
            points, and outside the knots when ``extrapolate`` is False.
        """
        nu = int(nu)
        if nu < 0:
            raise ValueError(f"derivative order must be >= 0, not {nu} (antiderivatives are not implemented)")
        xa = np.asarray(x, dtype=float)
        flat = xa.ravel()
        k = self.knots
        i = np.clip(np.searchsorted(k, flat, side="right") - 1, 0, k.size - 2)
        t = (flat - k[i]).reshape((-1,) + (1,) * (self.coefficients.ndim - 2))
        c = np.take(self.coefficients, i, axis=1)  # (4, len(x), ...): the piece of each point
        # d^nu/dx^nu of c0 t³ + c1 t² + c2 t + c3 by Horner's rule, in place
        if nu == 0:
            out = c[0] * t
            out += c[1]
            out *= t
            out += c[2]
            out *= t
            out += c[3]
        elif nu == 1:
            out = (3.0 * t) * c[0]
            out += 2.0 * c[1]
            out *= t
            out += c[2]
        elif nu == 2:
            out = (6.0 * t) * c[0]
            out += 2.0 * c[1]
        elif nu == 3:
            out = 6.0 * c[0]
        else:
            out = np.zeros_like(c[0])
        # NaN points give NaN for every order, as in scipy; so do points outside without extrapolation
        invalid = np.isnan(flat) if self.extrapolate else ~((flat >= k[0]) & (flat <= k[-1]))
        out[invalid] = np.nan
        return out.reshape(xa.shape + c.shape[2:])


def _solve_tridiagonal(lower: np.ndarray, diag: np.ndarray, upper: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve a tridiagonal system by the Thomas algorithm (Golub & Van Loan 2013, §4.3).

    Row i reads ``lower[i] u[i-1] + diag[i] u[i] + upper[i] u[i+1] = rhs[i]`` (``lower[0]`` and
    ``upper[-1]`` unused). ``rhs`` is (n, m); no pivoting (see the module docstring for why the
    spline systems need none).
    """
    n = diag.size
    ratio = np.empty(n)  # upper[i] / pivot[i]
    z = np.empty_like(rhs)
    pivot = diag[0]
    ratio[0] = upper[0] / pivot
    z[0] = rhs[0] / pivot
    for r in range(1, n):
        pivot = diag[r] - lower[r] * ratio[r - 1]
        ratio[r] = upper[r] / pivot
        z[r] = (rhs[r] - lower[r] * z[r - 1]) / pivot
    for r in range(n - 2, -1, -1):
        z[r] -= ratio[r] * z[r + 1]
    return z


def cubic_spline(x: np.ndarray, y: np.ndarray, bc_type: BoundaryCondition = "not-a-knot", *,
                 extrapolate: bool = True) -> PiecewiseCubic:
    """The C² cubic spline through (x, y) with the given end condition (matches scipy.interpolate.CubicSpline).

    Parameters
    ----------
    x : (n,) knots, strictly increasing and finite, n >= 2 (any unit; derivatives are per that unit).
    y : (n, ...) finite values at the knots; trailing axes are independent curves, so
        ``cubic_spline(x, np.eye(n), "natural")(t)`` is the (len(t), n) cardinal basis (column j the
        spline through the unit vector e_j).
    bc_type : ``"not-a-knot"`` (scipy's default) or ``"natural"`` (zero second derivative at both
        ends); see the module docstring for the equations and the 2- and 3-knot special cases.
    extrapolate : continue the end pieces beyond the knots (True) or give NaN there (False).

    Returns
    -------
    PiecewiseCubic
        Callable as ``spline(points, nu)``.

    Raises
    ------
    ValueError
        Bad shapes, fewer than 2 knots, knots not strictly increasing, non-finite data, or an
        unknown ``bc_type`` (the same conditions, and the same exception type, as scipy).
    """
    if bc_type not in ("not-a-knot", "natural"):
        raise ValueError(f"unknown boundary condition {bc_type!r}; use 'not-a-knot' or 'natural'")
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.ndim != 1:
        raise ValueError("`x` must be 1-dimensional.")
    n = x.size
    if n < 2:
        raise ValueError("`x` must contain at least 2 elements.")
    if y.ndim == 0 or y.shape[0] != n:
        raise ValueError(f"`y` has {y.shape[0] if y.ndim else 0} values along axis 0, `x` has {n}")
    if not np.all(np.isfinite(x)):
        raise ValueError("`x` must contain only finite values.")
    if not np.all(np.isfinite(y)):
        raise ValueError("`y` must contain only finite values.")
    dx = np.diff(x)
    if np.any(dx <= 0):
        raise ValueError("`x` must be strictly increasing sequence.")

    tail = y.shape[1:]
    y2 = y.reshape(n, -1)  # (n, m)
    dxc = dx[:, None]
    slope = np.diff(y2, axis=0) / dxc  # (n-1, m)

    if n == 2:
        s = np.vstack([slope, slope])  # the straight line, whatever the end condition
    elif n == 3 and bc_type == "not-a-knot":
        # the parabola through the three points (both not-a-knot rows coincide)
        a = np.array([[1.0, 1.0, 0.0],
                      [dx[1], 2.0 * (dx[0] + dx[1]), dx[0]],
                      [0.0, 1.0, 1.0]])
        b = np.vstack([2.0 * slope[0], 3.0 * (dxc[0] * slope[1] + dxc[1] * slope[0]), 2.0 * slope[1]])
        s = np.linalg.solve(a, b)
    else:
        lower = np.zeros(n)
        diag = np.empty(n)
        upper = np.zeros(n)
        b = np.empty_like(y2)
        lower[1:-1] = dx[1:]
        diag[1:-1] = 2.0 * (dx[:-1] + dx[1:])
        upper[1:-1] = dx[:-1]
        b[1:-1] = 3.0 * (dxc[1:] * slope[:-1] + dxc[:-1] * slope[1:])
        if bc_type == "not-a-knot":
            d = x[2] - x[0]
            diag[0], upper[0] = dx[1], d
            b[0] = ((dx[0] + 2.0 * d) * dx[1] * slope[0] + dx[0] ** 2 * slope[1]) / d
            d = x[-1] - x[-3]
            lower[-1], diag[-1] = d, dx[-2]
            b[-1] = (dx[-1] ** 2 * slope[-2] + (2.0 * d + dx[-1]) * dx[-2] * slope[-1]) / d
        else:  # natural: second derivative 0 at both ends
            diag[0], upper[0] = 2.0 * dx[0], dx[0]
            b[0] = 3.0 * (y2[1] - y2[0])
            lower[-1], diag[-1] = dx[-1], 2.0 * dx[-1]
            b[-1] = 3.0 * (y2[-1] - y2[-2])
        s = _solve_tridiagonal(lower, diag, upper, b)

    # cubic Hermite pieces from values and slopes (scipy.interpolate.CubicHermiteSpline)
    t = (s[:-1] + s[1:] - 2.0 * slope) / dxc
    c = np.stack([t / dxc, (slope - s[:-1]) / dxc - t, s[:-1], y2[:-1]])
    return PiecewiseCubic(knots=x.copy(), coefficients=c.reshape((4, n - 1) + tail), extrapolate=bool(extrapolate))
