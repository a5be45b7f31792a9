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
  step from it (the history runs on: the charge sees the jump as a kink, not a restart); a fit
  that moves the step is a step-size change like any other (the equal steps count anew, so an
  order decision reads differences of one step size);
- a new history (the first period, a reset, a state set from outside) starts at order 1 with
  Hairer & Wanner's starting step (scipy's select_initial_step);
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
# and controller cases take (docs/numerics.md, "The BDF stepper": fewer Jacobians after a
# give-up, at the same error).
NEWTON_MAXITER = 6
NEWTON_TOL = 0.1
MIN_FACTOR = 0.2
MIN_STEP_FRACTION = 1e-10   # of the period: below it the period fails
MAX_ATTEMPTS = 100000       # steps tried per period before it fails
MAX_FACTOR = 10.0
# A fit of the step to the period that moves it by less than this (relative) is round-off of
# the steps after a fit, not a step-size change: the equal steps go on counting.
FIT_ROUND_OFF = 1e-9
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
    local error allowed per step in those units; ``n_core`` the states the iteration and the
    norm hold (None: all; the rest are bookkeeping). Split by job as scipy's step is:
    :meth:`_try_step` (accepted, Newton failed or error failed), :meth:`_accept_step`,
    :meth:`_change_step`; the first step after a restart is chosen from the problem
    (:meth:`_first_step`).
    """

    def __init__(self, rhs, weights, tol: float, dt: float, n_core: int | None = None):
        self.rhs = rhs
        self.weights = np.asarray(weights, dtype=float)
        self.n_core = len(self.weights) if n_core is None else int(n_core)
        self.tol = float(tol)
        self.dt = float(dt)
        self.D = None
        self.steps = self.rejected = self.jacobians = self.factorizations = 0
        self.estimate = 0.0   # largest local error (tolerance units x tol) of accepted steps
        # order decisions taken, and those whose last order + 1 steps were not all one size
        # (the differences past the order then mix step sizes: a step change must reset the
        # count)
        self.order_decisions = self.mixed_decisions = 0
        self._accepted_h = []

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

    def _first_step(self, x, f0, u) -> float:
        """
        Return the first step of a new history: Hairer & Wanner's starting step.

        scipy's select_initial_step for an order-1 error estimate, its scale the tolerance's
        (the norm above), its interval the control period.
        """
        d0, d1 = self.norm(x), self.norm(f0)
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        h0 = min(h0, self.dt)
        f1 = self.rhs(x + h0 * f0, u)
        d2 = self.norm(f1 - f0) / h0
        if not math.isfinite(d2):   # the rate at the trial point is not usable: its step
            return h0
        if d1 <= 1e-15 and d2 <= 1e-15:
            h1 = max(1e-6, h0 * 1e-3)
        else:
            h1 = (0.01 / max(d1, d2)) ** 0.5
        return min(100.0 * h0, h1, self.dt)

    def _restart(self, x, u):
        f0 = self.rhs(x, u)
        if not np.all(np.isfinite(f0)):
            raise ArithmeticError('BDF: non-finite rate')
        self.h_abs = self._first_step(x, f0, u)
        self.D = np.zeros((MAX_ORDER + 3, len(x)))
        self.D[0] = x
        self.D[1] = f0 * self.h_abs
        self.order, self.n_equal_steps = 1, 0
        self.J = self.lu = None
        self.lu_c = 0.0
        self.jacobian_current = False

    def _rescale(self, factor, h_new):
        self.D[:self.order + 1] = rescale_matrix(self.order, factor).T @ self.D[:self.order + 1]
        self.h_abs = h_new

    def _change_step(self, factor):
        """Take a new step size h_abs * factor: the history rescaled, the equal steps anew."""
        self._rescale(factor, self.h_abs * factor)
        self.n_equal_steps = 0

    def _fit_to_period(self, left):
        """
        Fit the step to whole steps of equal size in what is ``left`` of the period.

        A change beyond round-off is a step-size change (the equal steps start anew); the
        round-off of the steps that follow a fit is not.
        """
        n_left = max(1, math.ceil(left / self.h_abs - 1e-9))
        h_fit = left / n_left
        if h_fit != self.h_abs:
            factor = h_fit / self.h_abs
            self._rescale(factor, h_fit)
            if abs(factor - 1.0) > FIT_ROUND_OFF:
                self.n_equal_steps = 0

    def period(self, x, u) -> np.ndarray:
        """Return the state one control period after x with the input u held."""
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
            self._fit_to_period(self.dt - t)
            h_abs = self.h_abs
            if not h_abs > MIN_STEP_FRACTION * self.dt:
                raise ArithmeticError('BDF: the step size underflowed')
            outcome, error_norm, n_iter = self._try_step(u)
            self.steps += 1
            if outcome == 'newton failed':
                self.rejected += 1
                self._change_step(0.5)
            elif outcome == 'error failed':
                self.rejected += 1
                self._change_step(max(MIN_FACTOR, safety(n_iter)
                                      * error_norm ** (-1.0 / (self.order + 1))))
            else:
                t += h_abs
                self._accepted_h = (self._accepted_h + [h_abs])[-(MAX_ORDER + 1):]
                self.estimate = max(self.estimate, error_norm * self.tol)
                self._accept_step(error_norm, n_iter)
        if not np.all(np.isfinite(self.D[0])):
            raise ArithmeticError('BDF: non-finite state')
        return self.D[0].copy()

    def _try_step(self, u):
        """Return ('accepted' | 'newton failed' | 'error failed', error norm, iterations)."""
        import scipy.linalg   # the reference only: the kernel has its own LU

        D, order = self.D, self.order
        nc = self.n_core
        y_predict = D[:order + 1].sum(axis=0)
        psi = D[1:order + 1].T @ GAMMA[1:order + 1] / ALPHA[order]
        c = self.h_abs / ALPHA[order]
        converged, n_iter = False, NEWTON_MAXITER
        while True:
            if self.J is None:
                self.J = self.jacobian(y_predict, u)
                self.jacobian_current = True
                self.lu = None
                if not np.all(np.isfinite(self.J)):   # never kept: a smaller step
                    self.J = None
                    break
            if self.lu is None or abs(c / self.lu_c - 1.0) > LU_KEEP:
                self.lu = scipy.linalg.lu_factor(np.eye(nc) - c * self.J[:nc])
                self.lu_c = c
                self.factorizations += 1
            converged, n_iter, d = self._newton(y_predict, u, c, psi)
            if converged or self.jacobian_current:
                break
            self.J = None
        if not converged:
            return 'newton failed', math.inf, n_iter
        self.d = d
        error_norm = self.norm(ERROR_CONST[order] * d)
        return ('error failed' if error_norm > 1.0 else 'accepted'), error_norm, n_iter

    def _accept_step(self, error_norm, n_iter):
        """Put the accepted step into the history; after order + 1 equal steps, choose anew."""
        D, order, d = self.D, self.order, self.d
        self.jacobian_current = False
        self.n_equal_steps += 1
        D[order + 2] = d - D[order + 1]
        D[order + 1] = d
        for i in reversed(range(order + 1)):
            D[i] += D[i + 1]
        if self.n_equal_steps < order + 1:
            return
        last = self._accepted_h[-(order + 1):]
        self.order_decisions += 1
        self.mixed_decisions += max(last) / min(last) - 1.0 > FIT_ROUND_OFF
        error_m = self.norm(ERROR_CONST[order - 1] * D[order]) if order > 1 else math.inf
        error_p = (self.norm(ERROR_CONST[order + 1] * D[order + 2])
                   if order < MAX_ORDER else math.inf)
        factors = [e ** (-1.0 / (order + k)) if e > 0.0 else math.inf
                   for k, e in enumerate((error_m, error_norm, error_p))]
        best = int(np.argmax(factors))
        self.order = order + best - 1
        self._change_step(min(MAX_FACTOR, safety(n_iter) * factors[best]))

    def _newton(self, y_predict, u, c, psi):
        """Return (converged, iterations, d = y - y_predict) of the simplified iteration."""
        import scipy.linalg

        d = np.zeros_like(y_predict)
        y = y_predict.copy()
        dy_norm_old = None
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
            dy_norm = self.norm(dy)
            if not dy_norm < math.inf:   # NaN or inf: an update that must not be taken
                break
            rate = None if dy_norm_old is None else dy_norm / dy_norm_old
            # a correction already within Newton's tolerance ends it: its rate, from two such
            # corrections, would be round-off (at rest it is noise around 1)
            small = dy_norm <= NEWTON_TOL
            if not small and rate is not None and (
                    rate >= 1.0 or rate ** (NEWTON_MAXITER - k) / (1.0 - rate) * dy_norm
                    > NEWTON_TOL):
                break
            y = y + dy
            d = d + dy
            if small or (rate is not None and rate / (1.0 - rate) * dy_norm < NEWTON_TOL):
                return True, k + 1, d
            dy_norm_old = dy_norm
        return False, k + 1, d


def safety(n_iter: int) -> float:
    """Return scipy's safety factor of a step size choice after n_iter Newton iterations."""
    return 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + n_iter)
