"""
Scenes: the validated, typed description of one simulation.

A scene file is a ROS 2 parameter file (``sim_node: ros__parameters: ...``) with the sections
``scene`` (structure and model switches), ``physics`` (the parameter set, SI units), ``integrator``
and ``rate_hz``; an optional ``node`` section belongs to the ROS node and is passed through.
Every key is checked at load: a missing or unknown key, a wrong type, or a value out of range is
refused with one :class:`SceneError` line naming the key, the value and the allowed range.

Units (stated once, used everywhere): m, kg, s, Pa, V, Ohm, F, C.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import sys
from typing import Any, Mapping

import numpy as np
import yaml

__all__ = ['SceneError', 'Physics', 'Scene', 'load_scene', 'scene_to_dict', 'find_config',
           'BEAMS', 'FIDELITIES', 'SOURCES', 'STRUCTURES', 'INITIAL_STATES', 'REST_BRANCHES']

BEAMS = ('simply_supported', 'fixed')
FIDELITIES = ('paper', 'consistent', 'exact')
SOURCES = ('rc', 'ideal')
STRUCTURES = ('single', 'plate', 'array')
# 'rest': every cell at its stable buckled equilibrium at 0 V (on rest_branch), at rest, no
# charge, no creep; 'released': the paper's start, q = q0 (nearly straight), released at t = 0
INITIAL_STATES = ('rest', 'released')
REST_BRANCHES = ('buckled+', 'buckled-')
EPS0 = 8.8541878128e-12  # F/m, vacuum permittivity


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
    'n_ritz': ('int', 1, True, 12, '-', 'Ritz terms per beam'),
    'creep': ('bool', 'Maxwell creep state'),
    'source': ('choice', SOURCES, 'electrical source model'),
    'monitor_power': ('bool', 'integrate the power balance'),
    'initial_state': ('choice', INITIAL_STATES, "initial state: 'rest' (stable buckled "
                      "equilibrium at 0 V) or 'released' (q = q0, the paper's start)"),
    'rest_branch': ('choice', REST_BRANCHES, "the rest state's side: 'buckled+' (q > 0) or "
                    "'buckled-' (q < 0)"),
}
# Optional keys and their values when a scene (or a log written before the key existed) omits
# them; every other key of SECTIONS must be given.
SECTION_DEFAULTS = {('scene', 'initial_state'): 'rest', ('scene', 'rest_branch'): 'buckled+'}
INTEGRATOR_SPEC = {
    'method': ('str', 'stepper name or auto'),
    'tolerance': ('float', 0.0, False, 0.1, '-', 'target error of auto'),
    'substeps': ('int', 0, True, 100000, '-',
                 'internal steps per control period (0 = adaptive from the tolerance)'),
}
# Optional section: how cells (each one DET and its pair of buckled beams, Section 3) are put
# together. Missing keys take STRUCTURE_DEFAULTS, so scene files without the section (and logs
# written before it existed) still load as one cell.
STRUCTURE_SPEC = {
    'type': ('choice', STRUCTURES, "'single' cell, two cells under a rigid 'plate' (Fig. 7), "
             "or an 'array' of independent copies"),
    'dets': ('names', 'DET names = order of the voltage command (default det0, det1, ...; '
             'left, right for a plate)'),
    'copies': ('int', 1, True, 100000, '-', 'array: number of independent actuators'),
    'plate_width': ('float', *_POS, 'm', 'plate: distance w between the two cells'),
    'plate_mass': ('float', 0.0, True, math.inf, 'kg', 'plate: mass (replaces the cells\' m)'),
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
TOP_SPEC = {
    'rate_hz': ('float', 0.0, False, 1.0e6, 'Hz', 'control rate'),
}
SECTIONS = {'scene': SCENE_SPEC, 'physics': PHYSICS_SPEC, 'integrator': INTEGRATOR_SPEC}


@dataclasses.dataclass(frozen=True)
class Physics:
    """The physical parameter set (SI units); see ``PHYSICS_SPEC`` for each entry."""

    l0: float
    A0: float
    d0: float
    n: int
    Y: float
    eps_r: float
    E_M: float
    eta_M: float
    eta_v: float
    E_b: float
    rho_b: float
    b_b: float
    t_b: float
    eta_b: float
    m: float
    Rs: float
    Rp: float
    v_max: float
    q0: float

    # Derived quantities (not parameters): named once here so every module agrees.
    @property
    def volume(self) -> float:
        """DET volume V = n A0 d0 (eq 46), m^3."""
        return self.n * self.A0 * self.d0

    @property
    def C0(self) -> float:
        """Capacitance of the undeformed DET, C0 = eps0 eps_r n A0 / d0 (eq 80), F."""
        return EPS0 * self.eps_r * self.n * self.A0 / self.d0

    @property
    def I(self) -> float:  # noqa: E743 - the paper's symbol for the second moment of area
        """Second moment of area of one beam, b t^3 / 12, m^4."""
        return self.b_b * self.t_b ** 3 / 12.0

    @property
    def area(self) -> float:
        """Cross-section area of one beam, m^2."""
        return self.b_b * self.t_b


@dataclasses.dataclass(frozen=True)
class Scene:
    """One validated scene: structure, model switches, physics, integrator and control rate."""

    beam: str
    eps_b: float
    fidelity: str
    n_ritz: int
    creep: bool
    source: str
    monitor_power: bool
    physics: Physics
    method: str
    tolerance: float
    substeps: int
    rate_hz: float
    node: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    structure: Mapping[str, Any] = dataclasses.field(
        default_factory=lambda: copy.deepcopy(STRUCTURE_DEFAULTS))
    dets: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    initial_state: str = 'rest'     # 'rest' | 'released' (INITIAL_STATES)
    rest_branch: str = 'buckled+'   # 'buckled+' | 'buckled-' (REST_BRANCHES)

    @property
    def det_names(self) -> tuple:
        """DET names in voltage-command order (one cell per DET)."""
        return tuple(self.structure['dets'])

    @property
    def n_dets(self) -> int:
        return len(self.structure['dets'])

    def cell_physics(self) -> tuple:
        """
        The physics of each cell: ``physics`` with the ``dets.<name>`` overrides and, for an
        array, the seeded spread (each spread_key times 1 + spread N(0, 1), clipped to +-3
        sigma); deterministic for a given scene.
        """
        base = dataclasses.asdict(self.physics)
        spread = self.structure['spread']
        rng = np.random.default_rng(self.structure['seed'])
        keys = list(self.structure['spread_keys'])
        cells = []
        for name in self.det_names:
            values = dict(base)
            if spread > 0.0:
                factors = np.clip(rng.standard_normal(len(keys)), -3.0, 3.0) * spread + 1.0
                for key, factor in zip(keys, factors):
                    values[key] = values[key] * float(factor)
            values.update(self.dets.get(name, {}))
            cells.append(Physics(**values))
        return tuple(cells)

    def cell_scene(self, index: int) -> 'Scene':
        """Cell ``index`` alone as a single-cell scene (its physics; for statics)."""
        physics = self.cell_physics()[index]
        return dataclasses.replace(self, physics=physics, dets={},
                                   structure=dict(STRUCTURE_DEFAULTS, dets=['det0']))

    @property
    def dt(self) -> float:
        """Control period, s."""
        return 1.0 / self.rate_hz

    @property
    def beam_length(self) -> float:
        """Beam length l = l0 (1 + eps_b) (eq 77), m."""
        return self.physics.l0 * (1.0 + self.eps_b)

    def replace(self, **changes) -> 'Scene':
        """Return a validated copy with dotted-key overrides (see :func:`load_scene`)."""
        return load_scene(scene_to_dict(self), overrides=changes)


def _fail(key, value, why):
    raise SceneError(f'scene key {key!r}: {why} (got {value!r})')


def _check_value(key, value, spec):
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
            _fail(key, value, f'must be a number in {unit}, not a string{hint}')
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            _fail(key, value, f'must be a number in {unit}')
        value = float(value)
    if not math.isfinite(value):
        _fail(key, value, 'must be finite')
    low_ok = value >= lower if inclusive else value > lower
    if not low_ok or value > upper:
        bracket = '[' if inclusive else '('
        _fail(key, value, f'out of range {bracket}{lower:g}, {upper:g}] {unit}')
    return value


def find_config(name: str = 'default.yaml') -> str:
    """
    Locate an installed scene file by name.

    Looks in the ament index share directory (colcon installs), ``<sys.prefix>/share`` (pip
    installs) and the source tree, in that order. A path to an existing file is returned as is.
    """
    if os.path.isfile(name):
        return name
    if not name.endswith('.yaml'):
        name += '.yaml'
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(os.path.join(get_package_share_directory('det_sim_ros'), 'config'))
    except Exception:  # no ament environment: fall back to the prefix and the source tree
        pass
    candidates.append(os.path.join(sys.prefix, 'share', 'det_sim_ros', 'config'))
    candidates.append(os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(
        os.path.abspath(__file__)))), 'config'))
    for folder in candidates:
        path = os.path.join(folder, name)
        if os.path.isfile(path):
            return path
    raise SceneError(f'scene file {name!r} not found in ' + ', '.join(candidates))


def _read_yaml(path):
    try:
        with open(path, encoding='utf-8') as stream:
            return yaml.safe_load(stream)
    except OSError as exc:
        raise SceneError(f'cannot read scene file {path!r}: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}' if mark is not None else ''
        raise SceneError(f'malformed YAML in {path!r}{where}: {exc}') from None


def _unwrap_ros_params(data, origin):
    """Accept ``{node: {ros__parameters: {...}}}`` (or ``/**``) as well as a bare mapping."""
    if not isinstance(data, dict):
        raise SceneError(f'scene {origin}: top level must be a mapping, got {type(data).__name__}')
    if len(data) == 1:
        (only, inner), = data.items()
        if isinstance(inner, dict) and 'ros__parameters' in inner:
            data = inner['ros__parameters']
            if not isinstance(data, dict):
                raise SceneError(f'scene {origin}: ros__parameters must be a mapping')
    return data


def _apply_override(data, key, value):
    if '.' not in key:
        owners = [s for s, spec in SECTIONS.items() if key in spec]
        if key in TOP_SPEC or not owners:
            data[key] = value
            return
        if len(owners) > 1:
            raise SceneError(f'override {key!r} is ambiguous: write one of '
                             + ', '.join(f'{o}.{key}' for o in owners))
        key = f'{owners[0]}.{key}'
    *path, leaf = key.split('.')
    target = data
    for part in path:   # 'physics.Rs', 'structure.type', 'dets.left.Rs'
        target = target.setdefault(part, {})
        if not isinstance(target, dict):
            raise SceneError(f'override {key!r}: {part!r} is not a mapping')
    target[leaf] = value


def load_scene(source: Any = 'default', overrides: Mapping[str, Any] | None = None) -> Scene:
    """
    Load and validate a scene.

    :param source: a path to a scene YAML, an installed scene name ('default'), or a mapping of
        the same shape (with or without the ``sim_node: ros__parameters:`` wrapper).
    :param overrides: ``{'physics.Rs': 1.0e3, 'eps_b': 0.25, ...}``; a key without a section is
        looked up in the section that has it. Values given as strings are parsed as YAML, and
        text such as '1.0e3' that YAML 1.1 keeps as a string is read as a number.
    :raises SceneError: one line naming the offending key, value and allowed range.
    """
    if isinstance(source, Scene):
        source = scene_to_dict(source)
    if isinstance(source, Mapping):
        data, origin = copy.deepcopy(dict(source)), '<dict>'
    else:
        origin = str(source)
        data = _read_yaml(find_config(origin))
    data = _unwrap_ros_params(data, origin)
    for key, value in (overrides or {}).items():
        if isinstance(value, str):   # command-line text: YAML, and numbers like 1.0e3 too
            try:
                value = yaml.safe_load(value)
            except yaml.YAMLError:
                pass
            if isinstance(value, str):
                try:
                    value = float(value)
                except ValueError:
                    pass
        _apply_override(data, key, value)

    unknown = set(data) - set(SECTIONS) - set(TOP_SPEC) - {'node', 'structure', 'dets'}
    if unknown:
        raise SceneError(f'unknown scene key {sorted(unknown)[0]!r}; known sections: '
                         + ', '.join(list(SECTIONS) + list(TOP_SPEC)
                                     + ['structure', 'dets', 'node']))
    values = {}
    for section, spec in SECTIONS.items():
        content = data.get(section)
        if not isinstance(content, dict):
            raise SceneError(f'scene key {section!r}: missing section (a mapping of '
                             + ', '.join(spec) + ')')
        for key in content:
            if key not in spec:
                raise SceneError(f'unknown scene key {section}.{key!r}; allowed: '
                                 + ', '.join(spec))
        for key, key_spec in spec.items():
            if key not in content and (section, key) in SECTION_DEFAULTS:
                values[(section, key)] = SECTION_DEFAULTS[(section, key)]
                continue
            if key not in content:
                raise SceneError(f'scene key {section}.{key!r}: missing ({key_spec[-1]})')
            values[(section, key)] = _check_value(f'{section}.{key}', content[key], key_spec)
    for key, key_spec in TOP_SPEC.items():
        if key not in data:
            raise SceneError(f'scene key {key!r}: missing ({key_spec[-1]})')
        values[('', key)] = _check_value(key, data[key], key_spec)
    node = data.get('node', {})
    if not isinstance(node, dict):
        raise SceneError(f"scene key 'node': must be a mapping (got {node!r})")

    structure, dets = _check_structure(data)
    physics = Physics(**{k: values[('physics', k)] for k in PHYSICS_SPEC})
    scene = Scene(**{k: values[('scene', k)] for k in SCENE_SPEC}, physics=physics,
                  **{k: values[('integrator', k)] for k in INTEGRATOR_SPEC},
                  rate_hz=values[('', 'rate_hz')], node=node, structure=structure, dets=dets)
    for name, cell in zip(scene.det_names, scene.cell_physics()):
        if cell.l0 * (1.0 + scene.eps_b) <= 0.0 or not all(
                math.isfinite(v) and v >= 0 for k, v in dataclasses.asdict(cell).items()
                if k != 'q0'):
            raise SceneError(f'DET {name!r}: physics out of range after overrides/spread')
    if scene.fidelity == 'paper' and scene.n_ritz != 1:
        raise SceneError(f"scene key 'scene.n_ritz': the 'paper' fidelity is one Ritz term; "
                         f"use fidelity 'consistent' for more (got {scene.n_ritz!r})")
    lam_pre = scene.beam_length / physics.l0
    if lam_pre <= 0.0:
        raise SceneError(f"scene key 'scene.eps_b': pre-stretch lambda = 1 + eps_b must be > 0 "
                         f'(got {scene.eps_b!r})')
    return scene


def _check_structure(data):
    """The optional 'structure' and 'dets' sections, validated, with names filled in."""
    content = data.get('structure', {})
    if not isinstance(content, dict):
        raise SceneError(f"scene key 'structure': must be a mapping (got {content!r})")
    for key in content:
        if key not in STRUCTURE_SPEC:
            raise SceneError(f'unknown scene key structure.{key!r}; allowed: '
                             + ', '.join(STRUCTURE_SPEC))
    structure = {key: _check_value(f'structure.{key}', content.get(key, default),
                                   STRUCTURE_SPEC[key])
                 for key, default in STRUCTURE_DEFAULTS.items()}
    kind = structure['type']
    count = {'single': 1, 'plate': 2, 'array': structure['copies']}[kind]
    names = structure['dets']
    if not names:
        names = ['left', 'right'] if kind == 'plate' else [f'det{i}' for i in range(count)]
    if len(names) != count:
        raise SceneError(f"scene key 'structure.dets': a {kind!r} structure has {count} DET(s), "
                         f'got {len(names)} name(s) {names}')
    structure['dets'] = names
    for key in structure['spread_keys']:
        if key not in PHYSICS_SPEC or PHYSICS_SPEC[key][0] != 'float':
            raise SceneError(f"scene key 'structure.spread_keys': {key!r} is not a float "
                             'physics key')
    dets = data.get('dets', {}) or {}
    if not isinstance(dets, dict):
        raise SceneError(f"scene key 'dets': must be a mapping of DET name to physics "
                         f'overrides (got {dets!r})')
    checked = {}
    for name, overrides in dets.items():
        if name not in names:
            raise SceneError(f'scene key dets.{name!r}: no DET of that name (DETs: {names})')
        if not isinstance(overrides, dict):
            raise SceneError(f'scene key dets.{name!r}: must be a mapping of physics keys')
        checked[name] = {}
        for key, value in overrides.items():
            if key not in PHYSICS_SPEC:
                raise SceneError(f'unknown scene key dets.{name}.{key!r}; allowed: '
                                 + ', '.join(PHYSICS_SPEC))
            checked[name][key] = _check_value(f'dets.{name}.{key}', value, PHYSICS_SPEC[key])
    return structure, checked


def scene_to_dict(scene: Scene, wrap: bool = False) -> dict:
    """Return the scene as the nested mapping a scene file holds (round-trips through load)."""
    data = {
        'scene': {k: getattr(scene, k) for k in SCENE_SPEC},
        'physics': dataclasses.asdict(scene.physics),
        'integrator': {k: getattr(scene, k) for k in INTEGRATOR_SPEC},
        'rate_hz': scene.rate_hz,
    }
    data['structure'] = copy.deepcopy(dict(scene.structure))
    if scene.dets:
        data['dets'] = copy.deepcopy({k: dict(v) for k, v in scene.dets.items()})
    if scene.node:
        data['node'] = copy.deepcopy(dict(scene.node))
    return {'sim_node': {'ros__parameters': data}} if wrap else data
