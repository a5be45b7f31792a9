"""
The parameters a fit moves: scene keys, their start values, bounds and scale.

A fitted parameter is a float key of the scene's ``physics`` section (every DET's, below any
``dets.<name>`` override) or ``scene.eps_b``. A parameter that must be positive is fitted in
log scale, z = ln(value), so a step means a relative change whatever its unit and it cannot
cross zero; the others in linear scale relative to their start, z = value / |start|.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Mapping, Sequence

import numpy as np

from .measurement import CalibrationError

__all__ = ['FitParameter', 'fit_parameters', 'FITTABLE', 'DEFAULT_SPAN', 'to_z', 'from_z']

# default bounds of a log-scale parameter: start / DEFAULT_SPAN .. start * DEFAULT_SPAN
DEFAULT_SPAN = 100.0
# keys that are floats but not model parameters to fit (the command limit, the released start)
_NOT_FITTED = {'v_max'}


def _fittable() -> dict:
    from ..scenes.keys import PHYSICS_SPEC, SCENE_SPEC
    keys = {f'physics.{k}': spec for k, spec in PHYSICS_SPEC.items()
            if spec[0] == 'float' and k not in _NOT_FITTED}
    keys.update({f'scene.{k}': spec for k, spec in SCENE_SPEC.items() if spec[0] == 'float'})
    return keys


FITTABLE = _fittable()


@dataclasses.dataclass(frozen=True)
class FitParameter:
    """One fitted scene key: start value, bounds, unit, and whether it is fitted in log scale."""

    key: str
    start: float
    lower: float
    upper: float
    log: bool
    unit: str

    @property
    def name(self) -> str:
        """Return the key without its section ('E_M')."""
        return self.key.rpartition('.')[2]

    def to_z(self, value: float) -> float:
        """Return the fit coordinate of a value."""
        return math.log(value) if self.log else value / self._scale

    def from_z(self, z: float) -> float:
        """Return the value of a fit coordinate."""
        return math.exp(z) if self.log else z * self._scale

    @property
    def _scale(self) -> float:
        return abs(self.start) or 1.0

    def scene_value(self, scene) -> float:
        """Return the parameter's value in a scene."""
        section, _, name = self.key.partition('.')
        return float(getattr(scene.physics if section == 'physics' else scene, name))


def _lookup(name: str) -> str:
    name = name.strip()
    if name in FITTABLE:
        return name
    owners = [key for key in FITTABLE if key.rpartition('.')[2] == name]
    if len(owners) == 1:
        return owners[0]
    short = sorted(key.rpartition('.')[2] for key in FITTABLE)
    raise CalibrationError(f'unknown parameter {name!r}; the fittable parameters are '
                           + ', '.join(short))


def _bounds(key: str, start: float, given) -> tuple:
    spec = FITTABLE[key]
    lower, inclusive, upper = spec[1], spec[2], spec[3]
    log = lower >= 0.0 and math.isinf(upper)
    name = key.rpartition('.')[2]
    if log and start <= 0.0:
        raise CalibrationError(f'{name}: the start value is {start:g}; a positive parameter is '
                               'fitted in log scale: give a start above 0')
    if log:
        low, high = start / DEFAULT_SPAN, start * DEFAULT_SPAN
    else:   # a bounded key (eps_b): its allowed range, just inside an open end
        margin = 1e-9 * (upper - lower)
        low, high = lower + (0.0 if inclusive else margin), upper - margin
    if given is not None:
        low = low if given[0] is None else float(given[0])
        high = high if given[1] is None else float(given[1])
    if log and low <= 0.0:
        raise CalibrationError(f'{name}: the lower bound must be above 0 (got {low:g}): it is '
                               'fitted in log scale')
    if not low < high:
        raise CalibrationError(f'{name}: the bounds [{low:g}, {high:g}] are empty')
    if not low <= start <= high:
        raise CalibrationError(f'{name}: the start {start:g} is outside the bounds '
                               f'[{low:g}, {high:g}]')
    return low, high, log


def fit_parameters(names: Sequence[str], scene, start: Mapping[str, float] | None = None,
                   bounds: Mapping[str, tuple] | None = None) -> list:
    """
    Return the :class:`FitParameter` list of ``names`` ('E_M' or 'physics.E_M').

    :param start: name -> start value (default: the scene's value).
    :param bounds: name -> (lower, upper), either None for the default (log scale: start /
        100 .. start * 100; linear: the key's allowed range).
    :raises CalibrationError: an unknown or repeated name, a start or bounds that do not fit.
    """
    keys = [_lookup(n) for n in names]
    if not keys:
        raise CalibrationError('no parameter to fit (--params E_M,eta_M,...)')
    if len(set(keys)) != len(keys):
        raise CalibrationError(f'a parameter is named twice: {list(names)}')
    starts = {_lookup(k): float(v) for k, v in (start or {}).items()}
    limits = {_lookup(k): v for k, v in (bounds or {}).items()}
    extra = sorted((set(starts) | set(limits)) - set(keys))
    if extra:
        raise CalibrationError(f'a start or bound for {extra[0].rpartition(".")[2]!r}, which is '
                               'not fitted (--params)')
    fitted = []
    for key in keys:
        spec = FITTABLE[key]
        probe = FitParameter(key, 1.0, 0.0, 1.0, False, spec[4])
        value = starts.get(key, probe.scene_value(scene))
        if not math.isfinite(value):
            raise CalibrationError(f'{probe.name}: the start is not a finite number')
        low, high, log = _bounds(key, value, limits.get(key))
        fitted.append(FitParameter(key, value, low, high, log, spec[4]))
    return fitted


def to_z(parameters, values) -> np.ndarray:
    """Return the fit coordinates of parameter values."""
    return np.array([p.to_z(v) for p, v in zip(parameters, values)])


def from_z(parameters, z) -> list:
    """Return the parameter values of fit coordinates."""
    return [p.from_z(float(v)) for p, v in zip(parameters, z)]
