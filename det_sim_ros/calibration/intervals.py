"""
What the log says about each fitted parameter: standard errors, intervals, identifiability.

From the weighted Jacobian J at the optimum (in the fit coordinates: log scale for positive
parameters) and the weighted residual r of N samples and p parameters: the residual variance
s² = |r|² / (N - p), the covariance s² (JᵀJ)⁻¹, and the 95 % interval from Student's t with
N - p degrees of freedom (log-scale parameters: value · exp(±t·se), so the interval is the
relative one the data give).

A parameter is flagged as not identifiable from the log when

- the Jacobian is rank-deficient along it: J's singular value decomposition has a direction
  whose singular value is below :data:`RCOND` times the largest, or whose standard error s / S_i
  exceeds :data:`MAX_DIRECTION_SE` (1 in log scale: the data cannot fix that combination to
  within a factor e), and the parameter's share of that direction (its component squared) is
  above :data:`SHARE`. Its interval is reported as not determined, and the others' intervals
  are computed with it held at its fitted value;
- or its correlation with another parameter exceeds :data:`MAX_CORRELATION` in magnitude: the
  log fixes a combination of the two, not each; its (wide) interval is still given.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ['Estimate', 'Uncertainty', 'uncertainty', 'RCOND', 'MAX_DIRECTION_SE', 'SHARE',
           'MAX_CORRELATION']

RCOND = 1e-8
MAX_DIRECTION_SE = 1.0
SHARE = 0.25
MAX_CORRELATION = 0.95


@dataclasses.dataclass
class Estimate:
    """One parameter's result: value, standard error and 95 % interval (SI units), flags."""

    key: str
    unit: str
    start: float
    value: float
    se: float            # standard error in the parameter's unit (inf: not determined)
    lower95: float
    upper95: float
    flags: list

    @property
    def name(self) -> str:
        """Return the key without its section."""
        return self.key.rpartition('.')[2]

    @property
    def identified(self) -> bool:
        """Return True when the log determines the parameter (no flag)."""
        return not self.flags

    @property
    def relative_se(self) -> float:
        """Return se / |value| (inf when not determined)."""
        return self.se / abs(self.value) if self.value else math.inf


@dataclasses.dataclass
class Uncertainty:
    """The statistics of a fit: estimates, correlation matrix, singular values, s²."""

    estimates: list
    correlation: np.ndarray
    singular_values: np.ndarray
    residual_variance: float
    dof: int


def _t95(dof: int) -> float:
    from scipy.stats import t
    return float(t.ppf(0.975, max(dof, 1)))


def _undetermined(J: np.ndarray, s2: float, free: list) -> list:
    """Return the indices (into ``free``) of parameters along undetermined directions."""
    if not free:
        return []
    _, S, Vt = np.linalg.svd(J[:, free], full_matrices=False)
    top = S[0] if S.size and S[0] > 0 else 1.0
    weak = [i for i, s in enumerate(S)
            if s <= RCOND * top or math.sqrt(s2) / max(s, 1e-300) > MAX_DIRECTION_SE]
    share = np.sum(Vt[weak] ** 2, axis=0) if weak else np.zeros(len(free))
    flagged = [j for j in range(len(free)) if share[j] > SHARE]
    if weak and not flagged:   # a direction spread thin: its largest share
        flagged = [int(np.argmax(share))]
    return flagged


def uncertainty(J: np.ndarray, residual: np.ndarray, parameters, z) -> Uncertainty:
    """Return the :class:`Uncertainty` of a fit from its weighted Jacobian and residual at z."""
    n, p = J.shape
    dof = max(n - p, 1)
    s2 = float(residual @ residual) / dof
    free, rank_flags = list(range(p)), {}
    while True:   # hold the undetermined ones until the rest is well conditioned
        drop = _undetermined(J, s2, free)
        if not drop:
            break
        for j in drop:
            rank_flags[free[j]] = ('not identifiable from this log: the Jacobian is '
                                   'rank-deficient along it (kept at its start value)')
        free = [f for i, f in enumerate(free) if i not in drop]
    cov = np.full((p, p), np.nan)
    if free:
        sub = J[:, free]
        cov[np.ix_(free, free)] = s2 * np.linalg.pinv(sub.T @ sub)
    se_z = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(invalid='ignore', divide='ignore'):
        correlation = cov / np.outer(se_z, se_z)
    flags = {j: [text] for j, text in rank_flags.items()}
    for i in free:
        for j in free:
            if i != j and abs(correlation[i, j]) > MAX_CORRELATION:
                flags.setdefault(i, []).append(
                    f'correlated with {parameters[j].name} (r = {correlation[i, j]:+.3f}): the '
                    'log fixes their combination, not each')
    t95 = _t95(dof)
    estimates = [_estimate(param, float(zi), se_z[i] if i in free else math.inf, t95,
                           flags.get(i, [])) for i, (param, zi) in enumerate(zip(parameters, z))]
    for i in rank_flags:   # it moves the residual by less than the noise: its start stays
        estimates[i].value = parameters[i].start
    singular = np.linalg.svd(J, compute_uv=False) if J.size else np.zeros(0)
    return Uncertainty(estimates, correlation, singular, s2, dof)


def _estimate(param, z: float, se_z: float, t95: float, flags: list) -> Estimate:
    value = param.from_z(z)
    if not math.isfinite(se_z):
        return Estimate(param.key, param.unit, param.start, value, math.inf,
                        0.0 if param.log else -math.inf, math.inf, flags)
    if param.log:
        se = value * se_z
        lower, upper = value * math.exp(-t95 * se_z), value * math.exp(t95 * se_z)
    else:
        se = abs(param.from_z(z + se_z) - value)
        lower, upper = value - t95 * se, value + t95 * se
    return Estimate(param.key, param.unit, param.start, value, se, lower, upper, flags)
