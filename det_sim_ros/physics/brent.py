"""Brent's root finder (scipy.optimize's brentq, without importing scipy.optimize)."""

from __future__ import annotations

__all__ = ['brentq']


def brentq(f, a, b, args=(), xtol=2e-12, rtol=8.9e-16, maxiter=100):
    """
    Return a root of f in [a, b] by Brent's method.

    f(a) and f(b) must have opposite signs. Brent's method (Brent 1973,
    'Algorithms for minimization without derivatives', ch. 4): inverse quadratic or secant steps
    kept inside the bracket, bisection when they would not shrink it fast enough; stops when the
    bracket is below xtol + rtol |x|. The same algorithm and stopping rule as scipy.optimize's
    brentq (test_statics checks equal roots), written here so that a node's start does not
    import scipy.optimize (its cost: docs/development.md, Costs the code is shaped by).
    """
    x_pre, x_cur = float(a), float(b)
    f_pre, f_cur = f(x_pre, *args), f(x_cur, *args)
    if f_pre == 0.0:
        return x_pre
    if f_cur == 0.0:
        return x_cur
    if (f_pre > 0.0) == (f_cur > 0.0):
        raise ValueError('brentq: f(a) and f(b) must have opposite signs')
    x_blk = f_blk = s_pre = s_cur = 0.0
    for _ in range(maxiter):
        if f_pre != 0.0 and f_cur != 0.0 and (f_pre > 0.0) != (f_cur > 0.0):
            x_blk, f_blk = x_pre, f_pre          # the bracket's other end
            s_pre = s_cur = x_cur - x_pre
        if abs(f_blk) < abs(f_cur):              # keep the best point in x_cur
            x_pre, x_cur, x_blk = x_cur, x_blk, x_cur
            f_pre, f_cur, f_blk = f_cur, f_blk, f_cur
        delta = (xtol + rtol * abs(x_cur)) / 2.0
        s_bis = (x_blk - x_cur) / 2.0
        if f_cur == 0.0 or abs(s_bis) < delta:
            return x_cur
        if abs(s_pre) > delta and abs(f_cur) < abs(f_pre):
            if x_pre == x_blk:                   # secant
                s_try = -f_cur * (x_cur - x_pre) / (f_cur - f_pre)
            else:                                # inverse quadratic interpolation
                d_pre = (f_pre - f_cur) / (x_pre - x_cur)
                d_blk = (f_blk - f_cur) / (x_blk - x_cur)
                s_try = -f_cur * (f_blk * d_blk - f_pre * d_pre) / (
                    d_blk * d_pre * (f_blk - f_pre))
            if 2.0 * abs(s_try) < min(abs(s_pre), 3.0 * abs(s_bis) - delta):
                s_pre, s_cur = s_cur, s_try      # the interpolation step is good
            else:
                s_pre = s_cur = s_bis
        else:
            s_pre = s_cur = s_bis
        x_pre, f_pre = x_cur, f_cur
        x_cur += s_cur if abs(s_cur) > delta else (delta if s_bis > 0.0 else -delta)
        f_cur = f(x_cur, *args)
    raise RuntimeError(f'brentq: no convergence in {maxiter} iterations')
