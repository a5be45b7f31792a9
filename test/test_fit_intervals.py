"""
Test the fit's standard errors and 95 % intervals against scipy's own statistics.

A straight line fitted by least squares has textbook intervals: scipy.stats.linregress gives
the slope's and intercept's standard errors and scipy.stats.t the two-sided 95 % quantile with
N - 2 degrees of freedom. The fit's interval code (calibration.intervals) sees the same problem
as a fit does: the weighted Jacobian and residual at the optimum in fit coordinates.
"""

import math

from det_sim_ros.calibration.intervals import uncertainty
from det_sim_ros.calibration.parameters import FitParameter
import numpy as np
import pytest
from scipy import stats

# few samples: t(10) at 0.975 is 2.23, 14 % above the normal's 1.96 and 23 % above t(10) at
# 0.95 (a one-sided quantile), so a wrong quantile moves the interval visibly
N = 12


def _line():
    """Return (x, y, linregress result) of a noisy line y = 2 + 0.5 x."""
    rng = np.random.default_rng(11)
    x = np.linspace(-1.0, 1.0, N)
    y = 2.0 + 0.5 * x + 0.1 * rng.standard_normal(N)
    return x, y, stats.linregress(x, y)


def test_linear_parameters_get_the_t_interval_of_ordinary_least_squares():
    """
    Check value, standard error and interval of a linear parameter against scipy.

    Both sides solve the same 12 x 2 least-squares problem (condition number of J ~ 2), by a
    pseudo-inverse and by linregress's sums: they agree to ~1e-15 relative; 1e-9 bounds that
    with any BLAS, and a quantile off by a few percent is far outside it.
    """
    x, y, line = _line()
    parameters = [FitParameter('physics.a', 1.0, -math.inf, math.inf, False, ''),
                  FitParameter('physics.b', 1.0, -math.inf, math.inf, False, '')]
    J = np.column_stack([np.ones(N), x])
    z = np.array([line.intercept, line.slope])
    result = uncertainty(J, y - J @ z, parameters, z)
    t95 = stats.t.ppf(0.975, N - 2)
    intercept, slope = result.estimates
    assert result.dof == N - 2
    for estimate, value, se in ((intercept, line.intercept, line.intercept_stderr),
                                (slope, line.slope, line.stderr)):
        assert estimate.identified
        assert estimate.value == pytest.approx(value, rel=1e-9)
        assert estimate.se == pytest.approx(se, rel=1e-9)
        assert (estimate.lower95, estimate.upper95) == pytest.approx(
            (value - t95 * se, value + t95 * se), rel=1e-9)


def test_log_scale_parameters_get_the_interval_of_their_logarithm():
    """
    Check a log-scale parameter's interval: exp of the t interval of its logarithm.

    The line is fitted in z = ln(value) (a positive parameter's fit coordinate); its interval is
    exp(z +- t se_z) with scipy's quantile and linregress's standard error. Same bound as above.
    """
    x, y, line = _line()
    parameters = [FitParameter('physics.a', 1.0, 0.0, math.inf, True, 'Pa'),
                  FitParameter('physics.b', 1.0, 0.0, math.inf, True, 'Pa')]
    J = np.column_stack([np.ones(N), x])
    z = np.array([line.intercept, line.slope])
    result = uncertainty(J, y - J @ z, parameters, z)
    t95 = stats.t.ppf(0.975, N - 2)
    for estimate, z_i, se in zip(result.estimates, z, (line.intercept_stderr, line.stderr)):
        assert estimate.value == pytest.approx(math.exp(z_i), rel=1e-9)
        assert (estimate.lower95, estimate.upper95) == pytest.approx(
            (math.exp(z_i - t95 * se), math.exp(z_i + t95 * se)), rel=1e-9)
