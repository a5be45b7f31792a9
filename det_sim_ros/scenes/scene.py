"""
Scenes: the validated, typed description of one simulation.

A scene file is a ROS 2 parameter file (``sim_node: ros__parameters: ...``) with the sections
``scene`` (structure and model switches), ``physics`` (the parameter set, SI units), ``integrator``
and ``rate_hz``; optional sections describe the ``structure``, per-DET overrides (``dets``) and
the high-voltage ``amplifier`` (:mod:`.amplifier`); an optional ``node`` section belongs to the
ROS node and is passed through.
A file names only what it changes from its base (``base:``, else config/default.yaml; see
:mod:`.files`), so the scene checked here is the file laid over its base. Every key is
checked at load: a missing or unknown key, a wrong type, or a value out of range is refused
with one :class:`SceneError` line naming the key, the value and the allowed range.

Units (stated once, used everywhere): m, kg, s, Pa, V, Ohm, F, C.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
from typing import Any, Mapping

import numpy as np
import yaml

from .amplifier import Amplifier, check_amplifier_section, check_amplifiers
from .files import find_config, read_scene_file, resolve_base, unwrap_ros_params
from .keys import (AMPLIFIER_DEFAULTS, AMPLIFIER_SPEC, BEAMS, check_section, check_value,
                   FIDELITIES, INITIAL_STATES, INTEGRATOR_SPEC, PHYSICS_SPEC, REST_BRANCHES,
                   SCENE_SPEC, SceneError, SECTION_DEFAULTS, SECTIONS, SOURCES,
                   STRUCTURE_DEFAULTS, STRUCTURE_SPEC, STRUCTURES, TOP_SPEC)
from .levels import resolve_level
from .sensors import check_sensors, Sensors, sensors_to_dict

__all__ = ['SceneError', 'Physics', 'Scene', 'load_scene', 'scene_to_dict', 'find_config',
           'BEAMS', 'FIDELITIES', 'SOURCES', 'STRUCTURES', 'INITIAL_STATES', 'REST_BRANCHES']

EPS0 = 8.8541878128e-12  # F/m, vacuum permittivity


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
        """Return the DET volume V = n A0 d0 (eq 46), m^3."""
        return self.n * self.A0 * self.d0

    @property
    def C0(self) -> float:
        """Return the capacitance of the undeformed DET, C0 = eps0 eps_r n A0 / d0 (eq 80), F."""
        return EPS0 * self.eps_r * self.n * self.A0 / self.d0

    @property
    def I(self) -> float:  # noqa: E743 - the paper's symbol for the second moment of area
        """Return the second moment of area of one beam, b t^3 / 12, m^4."""
        return self.b_b * self.t_b ** 3 / 12.0

    @property
    def area(self) -> float:
        """Return the cross-section area of one beam, m^2."""
        return self.b_b * self.t_b


@dataclasses.dataclass(frozen=True)
class Scene:
    """One validated scene: structure, model switches, physics, integrator and control rate."""

    beam: str
    eps_b: float
    fidelity: str
    n_ritz: int                     # as given: 0 = auto (see ritz_level)
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
    shapes: str = 'polynomial'      # as given: 'auto' | a Ritz family (SHAPES; see ritz_level)
    amplifier: Mapping[str, Any] = dataclasses.field(
        default_factory=lambda: dict(AMPLIFIER_DEFAULTS))
    sensors: Sensors = Sensors()    # what each output topic's sensor does (default: nothing)

    @property
    def det_names(self) -> tuple:
        """Return the DET names in voltage-command order (one cell per DET)."""
        return tuple(self.structure['dets'])

    @property
    def n_dets(self) -> int:
        """Return the number of DETs (one per cell, the voltage command's length)."""
        return len(self.structure['dets'])

    def cell_physics(self) -> tuple:
        """
        Return the physics of each cell, deterministic for a given scene.

        ``physics`` with the ``dets.<name>`` overrides and, for an array, the seeded spread (each
        spread_key times 1 + spread N(0, 1), clipped to +-3 sigma).
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
            values.update({key: value for key, value in self.dets.get(name, {}).items()
                           if key in PHYSICS_SPEC})
            cells.append(Physics(**values))
        return tuple(cells)

    def cell_amplifiers(self) -> tuple:
        """Return each DET's :class:`~.amplifier.Amplifier`: the section, then dets.<name>."""
        amps = []
        for name in self.det_names:
            values = dict(self.amplifier)
            values.update({key: value for key, value in self.dets.get(name, {}).items()
                           if key in AMPLIFIER_SPEC})
            amps.append(Amplifier(**values))
        return tuple(amps)

    @property
    def amplified(self) -> bool:
        """Return True if any DET's amplifier has a knob on (else the source is ideal)."""
        return any(amp.acts_on_command or amp.acts_in_circuit
                   for amp in self.cell_amplifiers())

    def cell_scene(self, index: int) -> 'Scene':
        """Return cell ``index`` alone as a single-cell scene (its physics; for statics)."""
        physics = self.cell_physics()[index]
        return dataclasses.replace(self, physics=physics, dets={},
                                   structure=dict(STRUCTURE_DEFAULTS, dets=['det0']))

    @property
    def ritz_level(self) -> tuple:
        """
        Return the (Ritz family, terms) the model runs: 'auto' and n_ritz 0 resolved per beam.

        The tables are det_sim_ros.scenes.levels'; 'paper' is one polynomial term.
        """
        return resolve_level(self.beam, self.fidelity, self.shapes, self.n_ritz)

    @property
    def fidelity_label(self) -> str:
        """
        Return the model level in a few words.

        E.g. 'exact buckling modes n_r=3', 'exact n_r=7' or 'paper (one term)'.
        """
        if self.fidelity == 'paper':
            return 'paper (one term)'
        shapes, n_ritz = self.ritz_level
        family = ' buckling modes' if shapes == 'buckling_modes' else ''
        return f'{self.fidelity}{family} n_r={n_ritz}'

    @property
    def dt(self) -> float:
        """Return the control period, s."""
        return 1.0 / self.rate_hz

    @property
    def beam_length(self) -> float:
        """Return the beam length l = l0 (1 + eps_b) (eq 77), m."""
        return self.physics.l0 * (1.0 + self.eps_b)

    def replace(self, **changes) -> 'Scene':
        """Return a validated copy with dotted-key overrides (see :func:`load_scene`)."""
        return load_scene(scene_to_dict(self), overrides=changes)


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


def _override_value(value):
    """
    Return an override as given, command-line text read as YAML.

    Numbers like 1.0e3 (a string in YAML 1.1) are read as numbers.
    """
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value)
        except yaml.YAMLError:
            pass
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                pass
    return value


def _checked_values(data):
    """Return (section, key) -> checked value of every section key and top-level key ('', key)."""
    optional = ['structure', 'dets', 'amplifier', 'sensors', 'node']
    unknown = set(data) - set(SECTIONS) - set(TOP_SPEC) - set(optional)
    if unknown:
        raise SceneError(f'unknown scene key {sorted(unknown)[0]!r}; known sections: '
                         + ', '.join(list(SECTIONS) + list(TOP_SPEC) + optional))
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
            values[(section, key)] = check_value(f'{section}.{key}', content[key], key_spec)
    for key, key_spec in TOP_SPEC.items():
        if key not in data:
            raise SceneError(f'scene key {key!r}: missing ({key_spec[-1]})')
        values[('', key)] = check_value(key, data[key], key_spec)
    return values


def _check_consistency(scene):
    """
    Check what spans several keys.

    The cells' physics after spread and the pre-stretch.
    """
    physics = scene.physics
    for name, cell in zip(scene.det_names, scene.cell_physics()):
        if cell.l0 * (1.0 + scene.eps_b) <= 0.0 or not all(
                math.isfinite(v) and v >= 0 for k, v in dataclasses.asdict(cell).items()
                if k != 'q0'):
            raise SceneError(f'DET {name!r}: physics out of range after overrides/spread')
    lam_pre = scene.beam_length / physics.l0
    if lam_pre <= 0.0:
        raise SceneError(f"scene key 'scene.eps_b': pre-stretch lambda = 1 + eps_b must be > 0 "
                         f'(got {scene.eps_b!r})')


def load_scene(source: Any = 'default', overrides: Mapping[str, Any] | None = None) -> Scene:
    """
    Load and validate a scene.

    :param source: a path to a scene YAML, an installed scene name ('default'), or a mapping of
        the same shape (with or without the ``sim_node: ros__parameters:`` wrapper). A file
        is laid over its base (its ``base:`` scene, else the shipped defaults); a mapping only
        over the base it names, if any.
    :param overrides: ``{'physics.Rs': 1.0e3, 'eps_b': 0.25, ...}``; a key without a section is
        looked up in the section that has it. Values given as strings are parsed as YAML, and
        text such as '1.0e3' that YAML 1.1 keeps as a string is read as a number.
    :raises SceneError: one line naming the offending key, value and allowed range.
    """
    if isinstance(source, Scene):
        source = scene_to_dict(source)
    if isinstance(source, Mapping):
        data = unwrap_ros_params(copy.deepcopy(dict(source)), '<dict>')
        data = resolve_base(data, os.getcwd(), '<dict>')
    else:
        data = read_scene_file(find_config(str(source)))
    for key, value in (overrides or {}).items():
        _apply_override(data, key, _override_value(value))
    values = _checked_values(data)
    node = data.get('node', {})
    if not isinstance(node, dict):
        raise SceneError(f"scene key 'node': must be a mapping (got {node!r})")

    structure, dets = _check_structure(data)
    if values[('scene', 'fidelity')] == 'paper':
        # the paper's model is its one-term shape: a scene that picks it over a base with more
        # terms (the shipped default) gets one term, whatever n_ritz it inherits
        values[('scene', 'n_ritz')] = 1
    sensors = check_sensors(data.get('sensors'))
    physics = Physics(**{k: values[('physics', k)] for k in PHYSICS_SPEC})
    scene = Scene(**{k: values[('scene', k)] for k in SCENE_SPEC}, physics=physics,
                  **{k: values[('integrator', k)] for k in INTEGRATOR_SPEC},
                  rate_hz=values[('', 'rate_hz')], node=node, structure=structure, dets=dets,
                  amplifier=check_amplifier_section(data.get('amplifier')), sensors=sensors)
    _check_consistency(scene)
    check_amplifiers(scene)
    return scene


def _check_structure(data):
    """Return the optional 'structure' and 'dets' sections, validated, with names filled in."""
    structure = check_section('structure', data.get('structure', {}), STRUCTURE_SPEC,
                              STRUCTURE_DEFAULTS)
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
            spec = PHYSICS_SPEC.get(key) or AMPLIFIER_SPEC.get(key)
            if spec is None:
                raise SceneError(f'unknown scene key dets.{name}.{key!r}; allowed: '
                                 + ', '.join(list(PHYSICS_SPEC) + list(AMPLIFIER_SPEC)))
            checked[name][key] = check_value(f'dets.{name}.{key}', value, spec)
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
    if scene.amplifier != AMPLIFIER_DEFAULTS:   # absent when off: logs stay as without it
        data['amplifier'] = dict(scene.amplifier)
    if scene.dets:
        data['dets'] = copy.deepcopy({k: dict(v) for k, v in scene.dets.items()})
    sensors = sensors_to_dict(scene.sensors)
    if sensors:   # (only when set: a scene without sensors reads and logs as before)
        data['sensors'] = sensors
    if scene.node:
        data['node'] = copy.deepcopy(dict(scene.node))
    return {'sim_node': {'ros__parameters': data}} if wrap else data
