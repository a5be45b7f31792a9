"""
The scene keys, their defaults and the check of one value against its entry.

For each section: each key's kind, range, unit and description, the defaults of the optional
keys, and the check of one value against its entry. Scene files, overrides and the node's
parameters are all checked here.
"""

from __future__ import annotations

import math

__all__ = ['SceneError', 'BEAMS', 'FIDELITIES', 'SHAPES', 'SOURCES', 'STRUCTURES',
           'INITIAL_STATES',
           'REST_BRANCHES', 'PHYSICS_SPEC', 'SCENE_SPEC', 'INTEGRATOR_SPEC', 'STRUCTURE_SPEC',
           'STRUCTURE_DEFAULTS', 'SECTION_DEFAULTS', 'TOP_SPEC', 'SECTIONS', 'check_value',
           'AMPLIFIER_SPEC', 'AMPLIFIER_DEFAULTS']

BEAMS = ('simply_supported', 'fixed')
FIDELITIES = ('paper', 'consistent', 'exact')
# the Ritz family: 'polynomial' (the paper's shape and admissible polynomials), 'buckling_modes'
# (the straight beam's Euler buckling modes), 'auto' (per beam: det_sim_ros.physics.shapes)
SHAPES = ('auto', 'polynomial', 'buckling_modes')
SOURCES = ('rc', 'ideal')
STRUCTURES = ('single', 'plate', 'array')
# 'rest': every cell at its stable buckled equilibrium at 0 V (on rest_branch), at rest, no
# charge, no creep; 'released': the paper's start, q = q0 (nearly straight), released at t = 0
INITIAL_STATES = ('rest', 'released')
REST_BRANCHES = ('buckled+', 'buckled-')


class SceneError(ValueError):
    """A scene or parameter value that cannot be simulated; the message names the key."""


# name: (kind, lower bound, lower bound inclusive, upper bound, unit, description)
_POS = (0.0, False, math.inf)
PHYSICS_SPEC = {
    'l0': ('float', *_POS, 'm', 'active DET length (stretch direction)'),
    'A0': ('float', *_POS, 'm^2', 'electrode area per layer'),
    'd0': ('float', *_POS, 'm', 'layer thickness'),
    'n': ('int', 1, True, 10000, '-', 'number of DET layers'),
    'Y': ('float', *_POS, 'Pa', 'Neo-Hooke modulus'),
    'eps_r': ('float', *_POS, '-', 'relative permittivity'),
    'E_M': ('float', 0.0, True, math.inf, 'Pa', 'Maxwell (creep) spring modulus'),
    'eta_M': ('float', *_POS, 'Pa s', 'Maxwell dashpot viscosity'),
    'eta_v': ('float', 0.0, True, math.inf, 'Pa s', 'DE Kelvin-Voigt viscosity'),
    'E_b': ('float', *_POS, 'Pa', "beam Young's modulus"),
    'rho_b': ('float', *_POS, 'kg/m^3', 'beam density'),
    'b_b': ('float', *_POS, 'm', 'beam width'),
    't_b': ('float', *_POS, 'm', 'beam thickness'),
    'eta_b': ('float', 0.0, True, math.inf, 'Pa s', 'beam Kelvin-Voigt viscosity'),
    'm': ('float', 0.0, True, math.inf, 'kg', 'interface mass'),
    'Rs': ('float', *_POS, 'Ohm', 'series resistance'),
    'Rp': ('float', *_POS, 'Ohm', 'parallel (leakage) resistance'),
    'v_max': ('float', *_POS, 'V', 'maximum voltage'),
    'q0': ('float', -math.inf, False, math.inf, 'm', 'initial deflection'),
}
SCENE_SPEC = {
    'beam': ('choice', BEAMS, 'mechanical interface'),
    'eps_b': ('float', -1.0, False, 2.0, '-', 'pre-strain, eq 77 (l = l0 (1 + eps_b) > 0)'),
    'fidelity': ('choice', FIDELITIES, 'model fidelity'),
    'n_ritz': ('int', 0, True, 12, '-', "Ritz terms per beam ('consistent', 'exact'; 0 = auto: "
               "the fewest right under switching; 'paper' is the one-term model and takes 1)"),
    'shapes': ('choice', SHAPES, 'Ritz family: polynomial, buckling_modes or auto (per beam, '
               'the one that needs the fewest terms)'),
    'creep': ('bool', 'Maxwell creep state'),
    'source': ('choice', SOURCES, 'electrical source model'),
    'monitor_power': ('bool', 'integrate the power balance'),
    'initial_state': ('choice', INITIAL_STATES, "initial state: 'rest' (stable buckled "
                      "equilibrium at 0 V) or 'released' (q = q0, the paper's start)"),
    'rest_branch': ('choice', REST_BRANCHES, "the rest state's side: 'buckled+' (q > 0) or "
                    "'buckled-' (q < 0)"),
}
# Optional keys and their values when a scene (a file, a mapping, or a log's stored scene) omits
# them; every other key of SECTIONS must be given.
SECTION_DEFAULTS = {('scene', 'initial_state'): 'rest', ('scene', 'rest_branch'): 'buckled+',
                    ('scene', 'shapes'): 'polynomial'}   # a scene or log from before the key
INTEGRATOR_SPEC = {
    'method': ('str', 'stepper name or auto'),
    'tolerance': ('float', 0.0, True, 0.1, '-', 'target error of auto (0 = auto: follows the '
                  'model error of the level, docs/fidelity.md)'),
    'substeps': ('int', 0, True, 100000, '-',
                 'internal steps per control period (0 = adaptive from the tolerance)'),
}
# Optional section: how cells (each one DET and its pair of buckled beams, Section 3) are put
# together. Missing keys take STRUCTURE_DEFAULTS, so a scene without the section (a file or a
# log's stored scene) loads as one cell.
STRUCTURE_SPEC = {
    'type': ('choice', STRUCTURES, "'single' cell, two cells under a rigid 'plate' (Fig. 7), "
             "or an 'array' of independent copies"),
    'dets': ('names', 'DET names = order of the voltage command (default det0, det1, ...; '
             'left, right for a plate)'),
    'copies': ('int', 1, True, 100000, '-', 'array: number of independent actuators'),
    'plate_width': ('float', *_POS, 'm', 'plate: distance w between the two cells'),
    'plate_mass': ('float', 0.0, True, math.inf, 'kg', "plate: mass (replaces the cells' m)"),
    'plate_inertia': ('float', 0.0, True, math.inf, 'kg m^2',
                      'plate: rotational inertia J about its centre'),
    'spread': ('float', 0.0, True, 0.3, '-', 'array: relative standard deviation of the '
               'spread_keys physics values per copy'),
    'spread_keys': ('names', 'array: physics keys that get the spread'),
    'seed': ('int', 0, True, 2 ** 31 - 1, '-', 'array: random seed of the spread'),
}
STRUCTURE_DEFAULTS = {'type': 'single', 'dets': [], 'copies': 1, 'plate_width': 0.06,
                      'plate_mass': 4.0e-3, 'plate_inertia': 1.2e-6, 'spread': 0.0,
                      'spread_keys': ['Y', 'E_b', 'Rs', 'm'], 'seed': 0}
# Optional section: the high-voltage amplifier between the command and each DET (every knob off
# by default: an ideal source). Its keys apply to every DET; ``dets.<name>`` may override them
# per DET like physics keys.
AMPLIFIER_SPEC = {
    'slew_rate': ('float', 0.0, True, math.inf, 'V/s', 'amplifier: output slew-rate limit '
                  '(0 = none)'),
    'current_limit': ('float', 0.0, True, math.inf, 'A', 'amplifier: output current limit, '
                      'at least the leakage current v_max/Rp (0 = none)'),
    'bandwidth': ('float', 0.0, True, math.inf, 'Hz', 'amplifier: first-order small-signal '
                  'bandwidth (0 = ideal)'),
    'dac_bits': ('int', 0, True, 32, '-', 'amplifier: command DAC resolution over [0, v_max] '
                 '(0 = ideal)'),
    'delay': ('float', 0.0, True, 3600.0, 's', 'amplifier: transport delay of the command, a '
              'whole number of control periods (0 = none)'),
    'offset': ('float', -math.inf, False, math.inf, 'V', 'amplifier: output offset added to '
               'the command'),
}
AMPLIFIER_DEFAULTS = {'slew_rate': 0.0, 'current_limit': 0.0, 'bandwidth': 0.0, 'dac_bits': 0,
                      'delay': 0.0, 'offset': 0.0}
TOP_SPEC = {
    'rate_hz': ('float', 0.0, False, 1.0e6, 'Hz', 'control rate'),
}
SECTIONS = {'scene': SCENE_SPEC, 'physics': PHYSICS_SPEC, 'integrator': INTEGRATOR_SPEC}


def check_section(where: str, content, spec, defaults) -> dict:
    """
    Return a mapping section's values checked against ``spec``, missing keys at ``defaults``.

    ``where`` is the section's dotted name (``structure``, ``amplifier``, ``sensors.charge``);
    :class:`SceneError` names a section that is not a mapping or a key it does not know.
    """
    if content is None:
        content = {}
    if not isinstance(content, dict):
        raise SceneError(f'scene key {where!r}: must be a mapping of '
                         + ', '.join(spec) + f' (got {content!r})')
    for key in content:
        if key not in spec:
            raise SceneError(f'unknown scene key {where}.{key!r}; allowed: ' + ', '.join(spec))
    return {key: check_value(f'{where}.{key}', content.get(key, default), spec[key])
            for key, default in defaults.items()}


def _fail(key, value, why):
    raise SceneError(f'scene key {key!r}: {why} (got {value!r})')


def _in_unit(unit: str) -> str:
    """Return ' in UNIT' for a message, '' for a dimensionless key (its unit '-')."""
    return '' if unit == '-' else f' in {unit}'


def check_value(key, value, spec):
    """
    Return ``value`` checked against its key's ``spec`` (an entry of the tables above).

    An int is read as a float for a float key; :class:`SceneError` naming the key otherwise.
    """
    kind = spec[0]
    if kind == 'bool':
        if not isinstance(value, bool):
            _fail(key, value, 'must be true or false')
        return value
    if kind == 'choice':
        if value not in spec[1]:
            _fail(key, value, 'must be one of ' + ', '.join(repr(c) for c in spec[1]))
        return value
    if kind == 'names':
        if (not isinstance(value, (list, tuple))
                or not all(isinstance(v, str) and v for v in value)):
            _fail(key, value, 'must be a list of non-empty strings')
        if len(set(value)) != len(value):
            _fail(key, value, 'names must be unique')
        return list(value)
    if kind == 'str':
        if not isinstance(value, str) or not value:
            _fail(key, value, 'must be a non-empty string')
        return value
    lower, inclusive, upper, unit = spec[1], spec[2], spec[3], spec[4]
    if kind == 'int':
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                _fail(key, value, 'must be an integer')
    else:
        if isinstance(value, str):
            hint = ''
            try:
                float(value)
                hint = '; YAML 1.1 reads an exponent without a sign as text: write e.g. 4.0e+9'
            except ValueError:
                pass
            _fail(key, value, f'must be a number{_in_unit(unit)}, not a string{hint}')
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            _fail(key, value, f'must be a number{_in_unit(unit)}')
        value = float(value)
    if not math.isfinite(value):
        _fail(key, value, 'must be finite')
    low_ok = value >= lower if inclusive else value > lower
    if not low_ok or value > upper:
        bracket = '[' if inclusive else '('
        unit_text = '' if unit == '-' else f' {unit}'
        _fail(key, value, f'out of range {bracket}{lower:g}, {upper:g}]{unit_text}')
    return value
