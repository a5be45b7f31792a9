"""
The numpy reference of the kernel's variable-order BDF stepper (``core/_csrc/stepping/bdf.c``).

The numerical differentiation formulas of orders 1 to 5 with a quasi-constant step (Shampine &
Reichelt, "The MATLAB ODE suite", SIAM J. Sci. Comput. 18, 1997; the scheme of scipy's
``integrate/_ivp/bdf.py``): the history as backward differences D of the interpolating
polynomial, a step-size change as its rescaling, a simplified Newton iteration with the
Jacobian kept while it converges, the local error from the last correction, the order raised
or lowered after order + 1 equal steps. Driven by control periods:

- the steps of a period fit it evenly (the last step never overshoots, no interpolation): the
  state at a period's end is the method's own, and an input that changes there starts the next
  step from it (the history runs on: the charge sees the jump as a kink, not a restart);
- the error norm is the largest weighted component (``weights``: 1 / scale) of the first
  ``n_core`` states, the tolerance absolute in those units;
- the states past ``n_core`` are bookkeeping integrals no rate reads (the power monitor's W_in,
  W_diss): the same formula steps them outside the iteration matrix and the norm, and a value
  written into them from outside (a recharge booked at an input jump) shifts their history
  instead of restarting it, so they never steer the steps.

The kernel is held to this module by test/test_bdf.py.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ['BdfStepper', 'MAX_ORDER']

MAX_ORDER = 5
# Newton gives up after NEWTON_MAXITER corrections (scipy: 4), and stops when its remaining
# error is below NEWTON_TOL of the local tolerance (CVODE's 0.1; scipy's min(0.03, sqrt(rtol))
# assumes a relative tolerance, where the tolerance here is absolute in the weighted norm).
# Chosen on the simply supported level (n_r 7, 3e-3) from the right-hand sides and LUs its 2 Hz
# and controller cases take: 4 and 0.03 took 14.6 and 31.2 per period (an LU counted as 3),
# 6 and 0.1 12.7 and 22.2 (fewer Jacobians after a give-up), at 0.59-0.75 % error either way;
# 8 or 0.2 gained less than 6 %.
NEWTON_MAXITER = 6
NEWTON_TOL = 0.1
MIN_FACTOR = 0.2
MIN_STEP_FRACTION = 1e-10   # of the period: below it the period fails
MAX_ATTEMPTS = 100000       # steps tried per period before it fails
MAX_FACTOR = 10.0
FD_RELATIVE = 1.4901161193847656e-08   # sqrt(eps): forward-difference Jacobian increments
# The LU of I - c J is kept while c = h / alpha_order stays within this fraction of the c it was
# factored at (CVODE's rule, dgmax 0.3): Newton then iterates with a slightly wrong matrix but
# converges to the same solution; a new step size every period would otherwise cost an LU.
LU_KEEP = 0.3
# The NDF's kappa (Shampine & Reichelt, Table 1): order 1-4 trade a little stability for a
# smaller error constant; order 5 is plain BDF.
KAPPA = np.array([0.0, -0.1850, -1.0 / 9.0, -0.0823, -0.0415, 0.0])
GAMMA = np.hstack((0.0, np.cumsum(1.0 / np.arange(1, MAX_ORDER + 1))))
ALPHA = (1.0 - KAPPA) * GAMMA
ERROR_CONST = KAPPA * GAMMA + 1.0 / np.arange(1, MAX_ORDER + 2)


def rescale_matrix(order: int, factor: float) -> np.ndarray:
    """Return RU: the differences D[:order + 1] of step h become RU.T @ D for step factor h."""
    def r(f):
        i = np.arange(1, order + 1)[:, None]
        j = np.arange(1, order + 1)
        m = np.zeros((order + 1, order + 1))
        m[1:, 1:] = (i - 1 - f * j) / i
        m[0] = 1.0
        return np.cumprod(m, axis=0)
    return r(factor) @ r(1.0)


class BdfStepper:
    """
    One coupled group's BDF history, advanced one control period at a time.

    ``rhs(x, u)`` returns dx/dt; ``weights`` the error norm's 1 / scale per state; ``tol`` the
    local error allowed per step in those units; ``h0`` the first step; ``n_core`` the states
    the iteration and the norm hold (None: all; the rest are bookkeeping).
    """

    def __init__(self, rhs, weights, tol: float, dt: float, h0: float,
                 n_core: int | None = None):
        self.rhs = rhs
        self.weights = np.asarray(weights, dtype=float)
        self.n_core = len(self.weights) if n_core is None else int(n_core)
        self.tol = float(tol)
        self.dt = float(dt)
        self.h0 = float(h0)
        self.newton_tol = NEWTON_TOL
        self.D = None
        self.steps = self.rejected = self.jacobians = self.factorizations = 0

    def norm(self, v) -> float:
        """Return the weighted max norm over the tolerance (NaN if a component is NaN)."""
        nc = self.n_core
        return float(np.max(np.abs(v[:nc]) * self.weights[:nc])) / self.tol

    def jacobian(self, x, u) -> np.ndarray:
        """
        Return df/dx_core by forward differences, increments sqrt(eps) max(|x_j|, scale_j).

        Every state's row, the core states' columns (no rate reads the bookkeeping states).
        """
        nc = self.n_core
        f0 = self.rhs(x, u)
        J = np.empty((len(x), nc))
        for j in range(nc):
            scale = 1.0 / self.weights[j] if self.weights[j] > 0.0 else 1.0
            xp = x.copy()
            xp[j] = x[j] + FD_RELATIVE * max(abs(x[j]), scale)
            J[:, j] = (self.rhs(xp, u) - f0) / (xp[j] - x[j])
        self.jacobians += 1
        return J

    def _restart(self, x, u):
        self.D = np.zeros((MAX_ORDER + 3, len(x)))
        self.D[0] = x
        self.D[1] = self.rhs(x, u) * self.h0
        self.h, self.order, self.equal_steps = self.h0, 1, 0
        self.J = self.lu = None
        self.lu_c = 0.0
        self.jacobian_current = False

    def _rescale(self, factor, h=None):
        self.D[:self.order + 1] = rescale_matrix(self.order, factor).T @ self.D[:self.order + 1]
        self.h = self.h * factor if h is None else h

    def period(self, x, u) -> np.ndarray:
        """Return the state one control period after x with the input u held."""
        import scipy.linalg   # the reference only: the kernel has its own LU

        x = np.asarray(x, dtype=float)
        if not np.all(np.isfinite(x)):
            raise ArithmeticError('BDF: non-finite state')
        nc = self.n_core
        if self.D is None or not np.array_equal(self.D[0, :nc], x[:nc]):
            self._restart(x, u)
        else:   # bookkeeping written from outside: a shift of its integral
            self.D[0, nc:] = x[nc:]
        t = 0.0
        attempts = 0
        while self.dt - t > 1e-12 * self.dt:
            if attempts == MAX_ATTEMPTS:
                raise ArithmeticError('BDF: no progress in this period')
            attempts += 1
            left = self.dt - t
            n_left = max(1, math.ceil(left / self.h - 1e-9))
            if left / n_left != self.h:
                self._rescale(left / n_left / self.h, left / n_left)
            D, order, h = self.D, self.order, self.h
            if not h > MIN_STEP_FRACTION * self.dt:
                raise ArithmeticError('BDF: the step size underflowed')
            y_predict = D[:order + 1].sum(axis=0)
            psi = D[1:order + 1].T @ GAMMA[1:order + 1] / ALPHA[order]
            c = h / ALPHA[order]
            while True:
                if self.J is None:
                    self.J = self.jacobian(y_predict, u)
                    self.jacobian_current = True
                    self.lu = None
                    if not np.all(np.isfinite(self.J)):   # never kept: a smaller step
                        self.J = None
                        converged = False
                        break
                if self.lu is None or abs(c / self.lu_c - 1.0) > LU_KEEP:
                    self.lu = scipy.linalg.lu_factor(np.eye(nc) - c * self.J[:nc])
                    self.lu_c = c
                    self.factorizations += 1
                converged, n_iter, y_new, d = self._newton(y_predict, u, c, psi)
                if converged or self.jacobian_current:
                    break
                self.J = None
            self.steps += 1
            if not converged:
                self.rejected += 1
                self._rescale(0.5)
                self.equal_steps = 0
                continue
            safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + n_iter)
            error = self.norm(ERROR_CONST[order] * d)
            if error > 1.0:
                self.rejected += 1
                self._rescale(max(MIN_FACTOR, safety * error ** (-1.0 / (order + 1))))
                self.equal_steps = 0
                continue
            self.jacobian_current = False
            t += h
            self.equal_steps += 1
            D[order + 2] = d - D[order + 1]
            D[order + 1] = d
            for i in reversed(range(order + 1)):
                D[i] += D[i + 1]
            if self.equal_steps < order + 1:
                continue
            lower = self.norm(ERROR_CONST[order - 1] * D[order]) if order > 1 else math.inf
            higher = (self.norm(ERROR_CONST[order + 1] * D[order + 2])
                      if order < MAX_ORDER else math.inf)
            factors = [e ** (-1.0 / (order + k)) if e > 0.0 else math.inf
                       for k, e in enumerate((lower, error, higher))]
            best = int(np.argmax(factors))
            self.order = order + best - 1
            self._rescale(min(MAX_FACTOR, safety * factors[best]))
            self.equal_steps = 0
        if not np.all(np.isfinite(self.D[0])):
            raise ArithmeticError('BDF: non-finite state')
        return self.D[0].copy()

    def _newton(self, y_predict, u, c, psi):
        import scipy.linalg

        d = np.zeros_like(y_predict)
        y = y_predict.copy()
        old = None
        for k in range(NEWTON_MAXITER):
            f = self.rhs(y, u)
            if not np.all(np.isfinite(f)):
                break
            # I - c J is block lower triangular: the core's block alone, the bookkeeping rows
            # by substitution after it
            dy = c * f - psi - d
            nc = self.n_core
            dy[:nc] = scipy.linalg.lu_solve(self.lu, dy[:nc])
            dy[nc:] += self.lu_c * (self.J[nc:] @ dy[:nc])
            size = self.norm(dy)
            if not size < math.inf:   # NaN or inf: an update that must not be taken
                break
            rate = None if old is None else size / old
            # a correction already within Newton's tolerance ends it: its rate, from two such
            # corrections, would be round-off (at rest it is noise around 1)
            small = size <= self.newton_tol
            if not small and rate is not None and (
                    rate >= 1.0 or rate ** (NEWTON_MAXITER - k) / (1.0 - rate) * size
                    > self.newton_tol):
                break
            y = y + dy
            d = d + dy
            if small or (rate is not None and rate / (1.0 - rate) * size < self.newton_tol):
                return True, k + 1, y, d
            old = size
        return False, k + 1, y, d
