"""
The methods: coefficient tables over one compiled stepping core, and the kinds of stepper.

Each :class:`Method` is data: stage nodes ``c`` and the coefficients a_ij, b_i written as sums of
``weight * phi_k(c_arg * h * L)`` (``k = -1``: a constant weight). The compiled core
(``ds_advance`` in det_sim_ros/core/_csrc/stepping/stages.c) treats x' = L x + N(x) with the stiff
diagonal L of the charge equation (dq_p/dt = -q_p / (C0 lam^2 Rs||Rp) + v/Rs, linear in q_p for
frozen q) exactly and everything else explicitly; for states with L = 0 every exponential method
reduces to the classical Runge-Kutta method with the same table (phi_k(0) = 1/k!).

Why exponential: the electrical time constant Rs C is hundreds of times shorter than the beam's
period at the shipped values, so explicit RK4 at the control period's step diverges; an
exponential update keeps every step size stable (tested from Rs = 1 Ohm to 1 MOhm) at the cost
of one exp per step and charge state.

Kinds: a method's :class:`StepperKind` (``KINDS``) is the one place the kinds of stepper differ:
'stages' (the table's stages), 'linearized' (the same with a dense linear part over the beams'
q, qdot) and 'bdf' (the variable-order BDF stepper, which has no table). A kind says how the
steps per period are controlled, which options the compiled stepper takes, which models it can
step and how it is described; the compiled core has the same kinds (core/_csrc/stepping/kind.c,
``kernel.STEPPER_KINDS``). A new table is a row of METHODS; a new kind is a class here and an
entry there.

How many steps: within a control period the steps are equal; their number is either fixed
(``integrator.substeps`` > 0, or a method without an embedded pair) or adapts per period to the
scene's tolerance from the method's embedded error estimate (:func:`step_control`). The 'step'
scenario spends most of its time settled, where one step per 1 ms period suffices, while a
snap-through needs tens: adapting takes several times fewer steps than a fixed count
(docs/numerics.md, "Stepping").
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..core import kernel

__all__ = ['Method', 'METHODS', 'MULTISTEP', 'BDF', 'BDF_MIN_COORDINATES', 'BDF_MIN_TOLERANCE',
           'StepperKind', 'KINDS',
           'bdf_weights', 'get_method',
           'choose_substeps', 'step_control', 'error_weights',
           'linear_refresh',
           'transient_settings', 'TransientSettings', 'StepControl', 'make_stepper',
           'advance', 'AUTO_TOLERANCE', 'integration_tolerance']


class StepperKind:
    """
    The table's stages, explicit or exponential in the charge: the kind 'stages'.

    A kind is what the compiled core calls it (``name``, one of ``kernel.STEPPER_KINDS``) and
    everything in which the kinds differ: how the steps per period are controlled
    (:meth:`control`), the options of the compiled stepper (:meth:`options`), the models it
    cannot step (:meth:`refusal`) and the phrase a log shows (:meth:`describe`). The other
    kinds subclass it.
    """

    name = 'stages'
    # its own steps and their control, whatever the table (no step count per period)
    own_step_control = False

    def refusal(self, model) -> str:
        """Return why the kind cannot step ``model`` ('' when it can)."""
        return ''

    def beam_rate(self, model) -> float:
        """Return the fastest beam rate the explicit stages must stay stable for, 1/s."""
        return model.fastest_beam_rate()

    def local_tolerance(self, method) -> float:
        """Return the embedded estimate's tolerance per unit of the scene's (see below)."""
        return LOCAL_TOLERANCE[method.embedded_order]

    def largest_count(self, model, n0: int, n_min: int) -> int:
        """Return the most steps a period may take when the count adapts."""
        return MAX_SUBSTEPS_FACTOR * max(n0, n_min)

    def control(self, method, model, substeps: int) -> 'StepControl':
        """
        Return the step-count controller's settings.

        Adaptive when ``substeps`` is 0 and the method has an embedded estimate, else fixed at
        ``substeps`` (0: :func:`choose_substeps`).
        """
        scene = model.scene
        tolerance = integration_tolerance(scene)
        beam_rate = self.beam_rate(model)
        n0 = substeps or choose_substeps(method, scene.dt, tolerance, beam_rate)
        if substeps or not method.adaptive:
            return StepControl(n0, 0.0, n0, n0, 1.0)
        n_min = min_substeps(scene.dt, beam_rate)
        return StepControl(max(n0, n_min), self.local_tolerance(method) * tolerance, n_min,
                           self.largest_count(model, n0, n_min), method.embedded_order + 1.0)

    def options(self, model, control: 'StepControl') -> dict:
        """Return the compiled stepper's options of this kind."""
        return {}

    def describe(self, method, control: 'StepControl', substeps: int) -> str:
        """Return the stepping in one phrase: 'etdrk4 x20' or 'etdrk4 adaptive (now x12)'."""
        if control.adaptive:
            return f'{method.name} adaptive (now x{substeps})'
        return f'{method.name} x{substeps}'


class LinearizedKind(StepperKind):
    """
    The table's stages with a dense linear part: the kind 'linearized'.

    The linear part also holds the Jacobian of the beams' q, qdot (taken at a period's start,
    see LINEAR_REFRESH), so their stiff modes are integrated exactly too and set no stability
    bound on the step.
    """

    name = 'linearized'

    def beam_rate(self, model) -> float:
        """Return 0: the stiff beam modes are in the linear part."""
        return 0.0

    def local_tolerance(self, method) -> float:
        """Return LINEARIZED_LOCAL_TOLERANCE (its estimate is weighted by phi functions)."""
        return LINEARIZED_LOCAL_TOLERANCE

    def largest_count(self, model, n0: int, n_min: int) -> int:
        """Return the bound of LINEARIZED_MAX_FACTOR (the ringing after a release)."""
        return LINEARIZED_MAX_FACTOR * max(n0, n_min,
                                           min_substeps(model.scene.dt, model.fastest_beam_rate()))

    def options(self, model, control: 'StepControl') -> dict:
        """Return when the linear part is taken anew: a state move and an input change."""
        return {'refresh': linear_refresh(integration_tolerance(model.scene)),
                'refresh_input': LINEAR_REFRESH_INPUT * _largest_v_max(model)}


class BdfKind(StepperKind):
    """
    The variable-order BDF stepper (core/_csrc/stepping/bdf.c): the kind 'bdf'.

    No table: its own step size and order control to a local error per step, implicit in
    every state, with whole control periods as its unit.
    """

    name = 'bdf'
    own_step_control = True

    def refusal(self, model) -> str:
        """Return why not when ``model`` is an array or has an amplifier."""
        a = model.arrays
        if a.n_groups != 1 or a.amplifier:
            return ('steps one coupled group without an amplifier (not an array, nor an '
                    'amplified supply)')
        return ''

    def control(self, method, model, substeps: int) -> 'StepControl':
        """Return its local error per step; the step counts are unused."""
        return StepControl(1, BDF_LOCAL_TOLERANCE * integration_tolerance(model.scene), 1, 1,
                           1.0)

    def options(self, model, control: 'StepControl') -> dict:
        """Return its tolerance and its norm's weights."""
        return {'tolerance': control.tolerance, 'weights': bdf_weights(model)}

    def describe(self, method, control: 'StepControl', substeps: int) -> str:
        """Return 'bdf adaptive (steps and order)'."""
        return f'{method.name} adaptive (steps and order)'


KINDS = {kind.name: kind for kind in (StepperKind(), LinearizedKind(), BdfKind())}
STAGES = KINDS['stages']


@dataclasses.dataclass(frozen=True)
class Method:
    """A fixed-step method as data (see module docstring)."""

    name: str
    order: int
    c: tuple
    terms: tuple          # (stage i or n_stages for b, j, k, c_arg, weight)
    exponential: bool
    description: str
    # Embedded error estimate h sum_j e_j N_j at L = 0 (main minus embedded solution): weights
    # e_0..e_{s-1} of the stages and e_s of f(x_new) (first same as last: the next step's
    # first stage), and the embedded solution's order. () = none: fixed substeps only.
    embedded: tuple = ()
    embedded_order: int = 0
    # how the compiled core steps it: the table's stages unless said otherwise
    kind: StepperKind = STAGES

    @property
    def n_stages(self) -> int:
        """Return the number of stages per step."""
        return len(self.c)

    def arrays(self):
        """Return the table as the float arrays the compiled core reads (terms by stage row)."""
        terms = sorted(self.terms, key=lambda term: term[0])
        return np.asarray(self.c, dtype=float), np.asarray(terms, dtype=float)

    @property
    def adaptive(self) -> bool:
        """Return whether the steps can follow an error estimate (an embedded pair, or BDF's)."""
        return bool(self.embedded) or self.kind.own_step_control


def _explicit(name, order, a, b, c, description):
    terms = [(i, j, -1, 0.0, a[i][j]) for i in range(len(c)) for j in range(i) if a[i][j]]
    terms += [(len(c), j, -1, 0.0, bj) for j, bj in enumerate(b) if bj]
    return Method(name, order, tuple(c), tuple(terms), False, description)


def _lawson(name, base, description):
    """
    Return the Lawson (integrating-factor) form of an explicit table.

    a_ij -> a_ij exp((c_i - c_j) h L), b_j -> b_j exp((1 - c_j) h L). Needs non-decreasing
    nodes c (else exp grows for stiff L).
    """
    c = base.c
    if any(b < a for a, b in zip(c, c[1:])):
        raise ValueError(f'{base.name}: Lawson form needs non-decreasing nodes c')
    s = len(c)
    terms = tuple((i, j, 0, (c[i] if i < s else 1.0) - c[j], w) for i, j, _, _, w in base.terms)
    return Method(name, base.order, c, terms, True, description, base.embedded,
                  base.embedded_order)


def _dormand_prince():
    """
    Return Dormand-Prince 5(4) (Dormand & Prince 1980) with its embedded error estimate.

    The table of scipy's RK45, checked equal by test_integrators.py. Written out so that
    importing the simulator does not import scipy.integrate (0.4 s of a node's start).
    """
    a = [[0, 0, 0, 0, 0, 0],
         [1 / 5, 0, 0, 0, 0, 0],
         [3 / 40, 9 / 40, 0, 0, 0, 0],
         [44 / 45, -56 / 15, 32 / 9, 0, 0, 0],
         [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0, 0],
         [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0]]
    b = [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84]
    c = [0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1]
    # y5 - y4 from the six stages and f(x_new) (scipy's RK45.E)
    e = [-71 / 57600, 0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40]
    method = _explicit('dp5', 5, a, b, c, 'Dormand-Prince order 5 (the table of scipy RK45)')
    return dataclasses.replace(method, embedded=tuple(e), embedded_order=4)


# Exponential tables: (i, j, k, c_arg, weight) means weight * phi_k(c_arg * h L).
_ETD_EULER = ((1, 0, 1, 1.0, 1.0),)
_ETD2 = (  # Cox & Matthews ETD2RK
    (1, 0, 1, 1.0, 1.0),
    (2, 0, 1, 1.0, 1.0), (2, 0, 2, 1.0, -1.0), (2, 1, 2, 1.0, 1.0),
)
_ETD_KROGSTAD = (  # Krogstad (2005) ETDRK4-B; Hochbruck & Ostermann, Acta Numerica 2010, Sec 2.3
    (1, 0, 1, 0.5, 0.5),
    (2, 0, 1, 0.5, 0.5), (2, 0, 2, 0.5, -1.0), (2, 1, 2, 0.5, 1.0),
    (3, 0, 1, 1.0, 1.0), (3, 0, 2, 1.0, -2.0), (3, 2, 2, 1.0, 2.0),
    (4, 0, 1, 1.0, 1.0), (4, 0, 2, 1.0, -3.0), (4, 0, 3, 1.0, 4.0),
    (4, 1, 2, 1.0, 2.0), (4, 1, 3, 1.0, -4.0),
    (4, 2, 2, 1.0, 2.0), (4, 2, 3, 1.0, -4.0),
    (4, 3, 2, 1.0, -1.0), (4, 3, 3, 1.0, 4.0),
)

_DP5 = _dormand_prince()
# RK4 with the third-order FSAL pair b^ = (1/6, 1/3, 1/3, 0, 1/6) (the fifth stage is f(x_new),
# the next step's first): y4 - y3 = h/6 (k4 - f(x_new)). Krogstad's ETDRK4 is RK4 at L = 0.
_RK4_EMBEDDED = ((0.0, 0.0, 0.0, 1 / 6, -1 / 6), 3)
_RK4 = dataclasses.replace(
    _explicit('rk4', 4, [[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1, 0]],
              [1 / 6, 1 / 3, 1 / 3, 1 / 6], [0, 0.5, 0.5, 1], 'classical Runge-Kutta'),
    embedded=_RK4_EMBEDDED[0], embedded_order=_RK4_EMBEDDED[1])
METHODS = {m.name: m for m in (
    _explicit('euler', 1, [[0]], [1], [0], 'explicit Euler (for tests and stress runs)'),
    _explicit('midpoint', 2, [[0, 0], [0.5, 0]], [0, 1], [0, 0.5], 'explicit midpoint'),
    _explicit('rk3', 3, [[0, 0, 0], [0.5, 0, 0], [-1, 2, 0]], [1 / 6, 2 / 3, 1 / 6],
              [0, 0.5, 1], "Kutta's third-order method"),
    _RK4,
    _DP5,
    _lawson('lawson4', _RK4, 'Lawson-RK4: integrating factor exp(h L) on the charge'),
    _lawson('lawson5', _DP5, 'Lawson-Dormand-Prince 5: integrating factor on the charge'),
    Method('exp_euler', 1, (0.0,), _ETD_EULER, True, 'exponential Euler'),
    Method('etd2', 2, (0.0, 1.0), _ETD2, True, 'Cox-Matthews ETD2RK'),
    Method('etdrk4', 4, (0.0, 0.5, 0.5, 1.0), _ETD_KROGSTAD, True,
           'Krogstad ETDRK4-B: classical RK4 on the mechanics, exact charge relaxation',
           *_RK4_EMBEDDED),
    Method('etdrk4_linearized', 4, (0.0, 0.5, 0.5, 1.0), _ETD_KROGSTAD, True,
           'Krogstad ETDRK4-B with the beams linearized: exact charge relaxation and exact '
           'linear beam modes (their Jacobian per control period)', *_RK4_EMBEDDED,
           KINDS['linearized']),
)}
# The variable-order BDF stepper (numerical differentiation formulas of orders 1-5, the scheme of
# scipy's BDF; core/_csrc/stepping/bdf.c, physics/reference_bdf.py): implicit in every state,
# one to three right-hand sides per step and an LU of I - h/alpha J when the step changes,
# the Jacobian kept while Newton converges. Where the beams have many stiff, heavily damped
# modes it needs far fewer right-hand sides than the exponential stages and no matrix phi
# functions (docs/fidelity.md, "Which method").
BDF = Method('bdf', 5, (0.0,), _ETD_EULER, False,
             'variable-order BDF (NDF orders 1-5) with its own step and order control',
             kind=KINDS['bdf'])
MULTISTEP = {BDF.name: BDF}
# 'auto' steps a single coupled group (no array copies, no amplifier) with BDF from this many
# Ritz coordinates in a beam (its n_ritz, whatever family: the states the stiff beam modes
# cost; det_sim_ros.scenes.levels), at a tolerance of at least BDF_MIN_TOLERANCE: there it
# steps the simply supported level's switching and controller cases faster at the same error;
# elsewhere the linearized stages stay ahead (at 3 buckling modes their phi functions are
# 6 x 6; at 1e-4 BDF's orders <= 5 take many steps). The measurements: docs/performance.md,
# "Methods side by side", and bench/controller_cost.py.
BDF_MIN_COORDINATES = 6
BDF_MIN_TOLERANCE = 1e-3
# The dense linear part of 'etdrk4_linearized' is taken anew at a period's start when the input
# changed or a q or qdot moved by more than this in the error norm's scale (beam length, length
# per period) since it was taken: between, the weights phi_k(c h A) of each step size are kept.
# A stale A only moves part of the linear dynamics into the explicit remainder, whose error the
# step control sees: a loose tolerance tolerates a staler A, so A lasts longer there (10 x the
# tolerance, within these bounds); tight tolerances keep the old 1e-2, where a staler A costs
# more steps than it saves. The step-size changes between refreshes cost little since the phi
# chains are kept (matrix_phi.c). The measurements that chose it: docs/numerics.md.
LINEAR_REFRESH = (1e-2, 3e-2)   # (at most, at least) of 10 x the tolerance


def linear_refresh(tolerance: float) -> float:
    """Return the state move (error-norm scale) past which A is taken anew, see above."""
    return min(LINEAR_REFRESH[1], max(LINEAR_REFRESH[0], 10.0 * tolerance))


# A is also taken anew when an input moved by more than this times v_max since it was taken
# (not at every change: a controller's small corrections every period took A, and the weights
# of each step size, anew every period; with this a dithered switching input runs faster at
# the same error: bench/work_precision_map.py's controller case, docs/numerics.md).
LINEAR_REFRESH_INPUT = 1e-2


# integrator.tolerance 0 ('auto'): the tolerance follows the model. Per level (fidelity, Ritz
# family, terms), the loosest tolerance of the work-precision map (bench/work_precision_map.py,
# docs/fidelity.md) at which the level's worst error against the continuum, over the step, 2 Hz
# switching and controller cases of both beams, stays within a third of its error at the map's
# tightest tolerance (its model error): total error = model error + integration error, and
# accuracy the model does not have is not worth its cost. Rows: (fidelity, family or '*', up to
# n_r, tolerance), first match. 'paper' keeps 1e-6: its runs are compared with the paper's own
# results, where the model itself is the reference (and its numbers stay).
AUTO_TOLERANCE = (   # each row's evidence: docs/fidelity.md, "How to choose"
    ('paper', '*', 12, 1e-6),
    ('consistent', '*', 12, 1e-2),
    ('exact', 'buckling_modes', 3, 1e-2),
    ('exact', 'buckling_modes', 5, 1e-3),
    ('exact', 'buckling_modes', 12, 1e-4),   # beyond the map: tighter than its last row
    ('exact', 'polynomial', 6, 1e-2),
    ('exact', 'polynomial', 7, 3e-3),
    ('exact', 'polynomial', 8, 1e-3),
    ('exact', 'polynomial', 9, 1e-4),
    ('exact', 'polynomial', 12, 1e-6),       # beyond the map: a converged reference's own
)


def integration_tolerance(scene) -> float:
    """Return the scene's integrator tolerance: its own, or AUTO_TOLERANCE's when it is 0."""
    if scene.tolerance > 0.0:
        return scene.tolerance
    shapes, n_ritz = scene.ritz_level
    return next(tol for fidelity, family, n_max, tol in AUTO_TOLERANCE
                if fidelity == scene.fidelity and family in ('*', shapes) and n_ritz <= n_max)


def get_method(name: str) -> Method:
    """Look up a method by name with a clear error."""
    try:
        return {**METHODS, **MULTISTEP}[name]
    except KeyError:
        raise ValueError(f'unknown integrator method {name!r}; known: '
                         + ', '.join(sorted({**METHODS, **MULTISTEP})) + ", or 'auto'") from None


# Step size that meets a tolerance: a method of order p reaches a relative Delta-y error of about
# ERROR_CONSTANT * (h / 1 ms)^p on the 'step' scenario; the largest over the six 'step' scenes,
# so the tolerance holds on each (docs/numerics.md, "The table steppers' calibrated constants").
ERROR_CONSTANT = {'etdrk4': 0.15, 'etdrk4_linearized': 0.15, 'dp5': 0.06}
MAX_STEP = 1.0e-3   # s: keeps h * omega_beam < 0.6 (stable for every table here)


STABLE_STEP = 2.0   # h * fastest beam rate: inside every table's stability region (RK4 2.8)


def choose_substeps(method: Method, dt: float, tolerance: float, beam_rate: float = 0.0) -> int:
    """
    Return the internal steps per control period for ``tolerance`` and the fastest beam mode.

    The expected error is then below ``tolerance`` and the explicit stages stay stable for the
    fastest beam mode the kind's stages see (``beam_rate``, 1/s; StepperKind.beam_rate, 0 for
    a dense linear part; see Model.fastest_beam_rate: it decides from about 6
    Ritz terms on).
    """
    const = ERROR_CONSTANT.get(method.name)
    if const is None:
        return min_substeps(dt, beam_rate)
    h_max = 1.0e-3 * (tolerance / const) ** (1.0 / method.order)
    return max(min_substeps(dt, beam_rate), int(math.ceil(dt / h_max - 1e-9)))


def min_substeps(dt: float, beam_rate: float = 0.0) -> int:
    """Return the fewest steps per period: h <= MAX_STEP and h * beam_rate <= STABLE_STEP."""
    h_max = MAX_STEP if beam_rate <= 0.0 else min(MAX_STEP, STABLE_STEP / beam_rate)
    return max(1, int(math.ceil(dt / h_max - 1e-9)))


# Adaptive step counts (ds_stages_period in _csrc/stepping/period.c): fixed steps inside each
# control period, their number chosen per period from the method's embedded error estimate,
# weighted per Ritz coordinate by 1/l (deflection) and dt/l (velocity) with l the cell's beam
# length. The local tolerance is LOCAL_TOLERANCE[embedded order] times the scene tolerance: the
# scene tolerance bounds the 'step' error (max over the run of |Delta-y error| / stroke), which
# accumulates local errors and amplifies them through snap-through, hence a local tolerance far
# below it (its calibration: docs/numerics.md, "The table steppers' calibrated constants").
LOCAL_TOLERANCE = {3: 5e-4, 4: 5e-4}
# 'etdrk4_linearized' (its estimate weighted by phi functions of the beams' Jacobian): tighter
# than the explicit tables' for the same error (docs/numerics.md, the same section).
LINEARIZED_LOCAL_TOLERANCE = 1.25e-4
# 'bdf': its local error per step (weighted max norm of bdf_weights) per unit of the scene
# tolerance, chosen with the work-precision map (bench/work_precision_map.py): at the simply
# supported level (n_r 7, 3e-3) it keeps the step and switching cases within the model's own
# error (docs/fidelity.md).
BDF_LOCAL_TOLERANCE = 3e-4
# At most MAX_SUBSTEPS_FACTOR times the fixed count of choose_substeps per period: bounds the
# cost of a period. A single actuator does not reach it, but an array whose copies switch at
# different times shares one count: unbounded, the slowest copy's count made every copy pay for
# it; the fixed count itself let the error exceed the tolerance (docs/numerics.md, the same
# section; bench/batch.py).
MAX_SUBSTEPS_FACTOR = 2
# A linearized method takes few steps while the beam is settled or slow, but the violent
# ringing right after a release or a snap-through (qdot ~ 5 m/s) can ask for more than twice
# the fixed count of the tolerance: its estimate follows the error there, so its bound is
# this many times the larger of that count and the count the explicit stages' stability
# would need.
LINEARIZED_MAX_FACTOR = 16


@dataclasses.dataclass(frozen=True)
class StepControl:
    """
    The per-period step-count controller's settings (ds_stages_period in _csrc/stepping/period.c).

    Fixed at ``substeps`` when ``tolerance`` is 0, else adaptive between ``min_substeps`` and
    ``max_substeps`` from the embedded estimate (which scales as n^-``exponent``).
    """

    substeps: int
    tolerance: float = 0.0
    min_substeps: int = 1
    max_substeps: int = 1
    exponent: float = 1.0

    @property
    def adaptive(self) -> bool:
        """Return whether the count adapts per period (a tolerance is set)."""
        return self.tolerance > 0.0


def step_control(method: Method, model, substeps: int = 0) -> StepControl:
    """
    Return the step-count controller's settings of ``method`` for ``model``.

    Its kind's (:meth:`StepperKind.control`): for the tables, adaptive when ``substeps`` is 0
    and the method has an embedded estimate, else fixed at ``substeps`` (0:
    :func:`choose_substeps`).
    """
    return method.kind.control(method, model, substeps)


def make_stepper(model, method: Method, control: StepControl, dt: float,
                 transient: 'TransientSettings | None' = None):
    """
    Return the compiled stepper (det_sim_ros.core.kernel.Stepper) of ``method`` for ``model``.

    ``transient``: how charge transients are resolved; None: not at all.
    """
    transient = transient or TransientSettings()
    c, terms = method.arrays()
    return kernel.Stepper(model.kernel, c, np.ascontiguousarray(terms.reshape(-1, 5)),
                          np.asarray(method.embedded, dtype=float), error_weights(model),
                          dt=float(dt), z_tol=float(transient.z_tol),
                          fine=float(transient.fine), substeps=int(control.substeps),
                          tolerance=float(control.tolerance),
                          min_substeps=int(control.min_substeps),
                          max_substeps=int(control.max_substeps),
                          exponent=float(control.exponent),
                          jump_ref=float(transient.jump_ref), kind=method.kind.name,
                          options=method.kind.options(model, control))


def _largest_v_max(model) -> float:
    """Return the largest v_max of the model's cells, V."""
    return max(cell.v_max for cell in model.scene.cell_physics())


def error_weights(model) -> np.ndarray:
    """
    Return 1 / scale of each state in the embedded error norm.

    q_j is scaled by its cell's beam length l, qdot_j by l / dt; the other states are not in the
    norm (0).
    """
    a = model.arrays
    w = np.zeros(a.n_state)
    for c in range(a.n_cells):
        s = a.cell_slice(c)
        w[s] = 1.0 / a.length[c]
        w[a.n_q + s.start:a.n_q + s.stop] = model.scene.dt / a.length[c]
    return w


# The BDF stepper's norm (core/_csrc/stepping/bdf.c, physics/reference_bdf.py) holds every
# state it integrates implicitly: the beams' as error_weights, the charge on C0 v_max and the
# creep strain on 1 (strain), both BDF_SLOW_WEIGHT times looser. Chosen on the simply supported
# level (n_r 7, 3e-3) over its step, 2 Hz switching and controller cases and a dithered hold
# (docs/numerics.md, "The BDF stepper", has the scan): tighter resolves every dither jump's
# charge transient at great cost, looser leaves the charge out of Newton's test and is no
# faster. The power monitor's integrals (W_in, W_diss) feed back on nothing: the stepper keeps
# them out of its norm and its iteration matrix whatever their weight (bdf.h, n_core).
BDF_SLOW_WEIGHT = 1e-4


def bdf_weights(model) -> np.ndarray:
    """Return 1 / scale of each state in the BDF stepper's error and Newton norms."""
    a = model.arrays
    w = error_weights(model)
    v_max = [cell.v_max for cell in model.scene.cell_physics()]
    for i, name in enumerate(model.state_names):
        if name.startswith('q_p['):
            cell = int(name[4:-1])
            w[i] = BDF_SLOW_WEIGHT / (a.C0[cell] * v_max[cell])
        elif name.startswith(('eps_E[', 'v_a[')):
            w[i] = BDF_SLOW_WEIGHT
    return w


# Resolving the charge transient after an input jump (fixed_period in _csrc/stepping/period.c):
# steps of TRANSIENT_FINE * tau while the charge lag exceeds TRANSIENT_CHARGE * tolerance * C0
# v_max. The first step after a jump is TRANSIENT_FINE * tau at a tolerance of 3e-6, scaled as
# tolerance^(1/4) so the first step follows the tolerance; later ones grow geometrically (see
# fixed_period; its calibration: docs/numerics.md, "The table steppers' calibrated constants").
TRANSIENT_FINE = 0.35      # at a tolerance of 3e-6
TRANSIENT_CHARGE = 1.0


@dataclasses.dataclass(frozen=True)
class TransientSettings:
    """
    How the stepper resolves the charge transient after an input jump.

    See fixed_period in _csrc/stepping/period.c: while the charge lag exceeds ``z_tol`` (C; 0:
    never), graded steps from ``fine`` * tau, ``fine`` sized for jumps of ``jump_ref`` (V); a
    smaller jump du starts at fine * (jump_ref / du)^(1/5), the same local error for its smaller
    lag (0: every jump at ``fine``).
    """

    z_tol: float = 0.0
    fine: float = 1.0
    jump_ref: float = 0.0


def transient_settings(method: Method, scene) -> TransientSettings:
    """
    Return the stepper's :class:`TransientSettings` for ``scene``.

    Off unless the method is exponential and the scene has an RC source (explicit methods must
    step below the charge time constant anyway, and an ideal source has no charge transient).
    ``fine`` follows the tolerance and was calibrated on the 'step' scenes, whose jumps are
    v_max: so ``jump_ref`` = v_max.
    """
    tolerance = integration_tolerance(scene)
    fine = min(1.0, max(0.05, TRANSIENT_FINE * (tolerance / 3e-6) ** 0.25))
    if not method.exponential or scene.source != 'rc':
        return TransientSettings(0.0, fine, 0.0)
    p = scene.physics
    return TransientSettings(TRANSIENT_CHARGE * tolerance * p.C0 * p.v_max, fine,
                             p.v_max)


def advance(x, u, model, method: Method, h: float, n_steps: int) -> int:
    """
    Advance ``x`` in place by ``n_steps`` steps of ``h`` with ``u`` held.

    Return a kernel status (x is unchanged on failure). Builds a stepper per call: for tests and
    one-offs.
    """
    stepper = make_stepper(model, method, StepControl(max(1, n_steps)), max(h, 1e-300))
    return stepper.advance(x, np.asarray(u, dtype=float), float(h), int(n_steps))
