"""
Replay of MCAP run logs without ROS.

Re-simulate a log bit-for-bit, and record a run offline with the node's bytes.

``det_sim replay resim LOG`` (also ``det_sim_replay resim LOG``) feeds the logged voltage
commands through the model with the logged scene and stepper, and compares with the logged
outputs. The timing rule is the node's:
a command logged at sim time t_k is applied before the step from t_k to t_{k+1}; an output
stamped t_k is the result of the step that ended at t_k (t_0: the initial state). With the same
scene and stepper the outputs are reproduced bit-for-bit (the simulator is fixed-step and
deterministic), so the default tolerance is 0.

Republishing a log on a ROS graph is det_sim_ros.ros.play; the command line (``play``, ``info``,
``recover``) is the ``replay`` verb of ``det_sim``.
"""

from __future__ import annotations

import ast
import dataclasses
import math
from typing import Callable, Mapping, Sequence

from .contract import basename as _basename
from .contract import (CdrError, COMMAND_TOPIC, COMMAND_TOPICS, CommandDecoder,
                       decode_joint_state, encode_float64_multi_array, encode_joint_state,
                       JOINT_COMMAND_TOPIC, OUTPUT_FIELDS, OutputContract, rest_shortening,
                       rest_shortenings, stamp_ns, TOPIC_TYPES)
from .log import LogReader, Recorder
from .sensing import is_truth_topic, make_outputs, SensedOutputs

__all__ = ['OUTPUT_FIELDS', 'COMMAND_TOPICS', 'ResimResult', 'resimulate', 'simulate_to_log',
           'OutputContract', 'rest_shortening', 'rest_shortenings', 'scene_from_log']

# The topic contract (topics, channels, y0, structure outputs, commands) is
# det_sim_ros.io.contract; a log holds the per-DET y0 as metadata 'y0' (a float for one DET, a
# list for several).


def _logged_y0(text: str | None, n: int) -> list[float] | None:
    """Metadata 'y0' (a float for one DET, a list for several), None if absent or not n values."""
    if not text:
        return None
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return None
    values = value if isinstance(value, (list, tuple)) else [value]
    return [float(v) for v in values] if len(values) == n else None


def _logged_x0(text: str | None, n: int):
    """
    Return the metadata 'x0' (the run's initial state vector), if valid.

    None if absent or not n finite values.
    """
    if not text:
        return None
    try:
        values = [float(v) for v in ast.literal_eval(text)]
    except (ValueError, SyntaxError, TypeError):
        return None
    return values if len(values) == n and all(math.isfinite(v) for v in values) else None


# -- re-simulation -------------------------------------------------------------------------------

@dataclasses.dataclass
class ResimResult:
    """Outcome of :func:`resimulate`."""

    max_deviation: dict[str, float]  # 'topic.field (output)' -> max |logged - resimulated|
    compared: dict[str, int]         # same keys -> number of samples compared
    commands: int = 0
    steps: int = 0
    skipped: int = 0                 # logged outputs that could not be matched to a step
    fault: str = ''
    complete: bool = True            # the log was a finished file
    method: str = ''
    substeps: int = 0                # 0: adaptive

    def ok(self, tolerance: float = 0.0) -> bool:
        """Return True if every compared output is within ``tolerance`` and nothing went wrong."""
        return (not self.fault and bool(self.compared) and self.skipped == 0
                and all(v <= tolerance for v in self.max_deviation.values()))

    def table(self) -> str:
        """Return a plain-text table of the deviations."""
        width = max([len(k) for k in self.max_deviation] + [6])
        lines = [f"{'output':<{width}}  {'samples':>8}  max |deviation|"]
        for key, value in self.max_deviation.items():
            lines.append(f'{key:<{width}}  {self.compared[key]:>8}  {value:.6g}')
        stepping = f'x {self.substeps}' if self.substeps else 'adaptive'
        lines.append(f'{self.commands} commands, {self.steps} steps, stepper {self.method} '
                     f'{stepping}' + ('' if self.complete else ', log unfinished (recovered)')
                     + (f', {self.skipped} outputs unmatched' if self.skipped else '')
                     + (f', fault: {self.fault}' if self.fault else ''))
        return '\n'.join(lines)


def scene_from_log(reader: LogReader):
    """Return the scene a log recorded (its bases resolved), validated."""
    import yaml
    from ..scenes.scene import load_scene
    text = reader.scene_yaml
    if not text:
        raise ValueError(f'{reader.files[0]}: the log holds no scene (det_sim_ros metadata)')
    data = yaml.safe_load(text)
    inner = data
    if isinstance(data, dict) and len(data) == 1:
        (only,) = data.values()
        if isinstance(only, dict) and 'ros__parameters' in only:
            inner = only['ros__parameters']
    section = inner.get('scene') if isinstance(inner, dict) else None
    if isinstance(section, dict):
        # logs written before scene.initial_state existed started released from q0
        section.setdefault('initial_state', 'released')
    return load_scene(data)


def resimulate(log, method: str | None = None, substeps: int | None = None,
               output_fields: Mapping[str, Mapping[str, str]] | None = None) -> ResimResult:
    """
    Re-run a logged run in-process and compare with its logged outputs.

    :param log: an MCAP file, a list of split files or a directory.
    :param method, substeps: the stepper (default: as logged in the ``det_sim_ros`` metadata,
        else the scene's).
    """
    reader = LogReader(log)
    info = reader.info
    if method is None:
        method = info.get('method') or None
    if substeps is None and info.get('substeps'):
        substeps = int(info['substeps'])
    resim = _Resim(reader, method, substeps, dict(output_fields or OUTPUT_FIELDS))
    for message in reader.messages():
        if not resim.feed(message):
            break
    resim.result.complete = reader.complete
    return resim.result


class _Resim:
    """
    One re-simulation of a log.

    The simulator is stepped to each logged message's time, the commands applied, the logged
    outputs compared with the simulated ones into a :class:`ResimResult`.
    """

    def __init__(self, reader, method, substeps, fields):
        import numpy as np
        from ..physics.model import ModelDomainError
        from ..sim.simulator import Simulator
        self._domain_error = ModelDomainError
        scene = scene_from_log(reader)
        info = reader.info
        sim = Simulator(scene, method=method, substeps=substeps)
        x0 = _logged_x0(info.get('x0'), sim.model.n_states)
        if x0 is not None:   # the logged initial state (bit-exact even if its solve changes)
            sim.x0 = np.array(x0)
            sim.reset()
        self.sim = sim
        self.fields = fields
        self.det_names = list(sim.model.input_names)
        self.contract = OutputContract(sim.model, _logged_y0(info.get('y0'), sim.model.n_inputs),
                                       fields)
        self.decoder = CommandDecoder(self.det_names, scene.physics.v_max)
        self.structure_key = (f'{self.contract.structure_topic}.position '
                              f"({', '.join(self.contract.structure_outputs)})")
        self.dt_ns = sim.dt * 1e9
        self.result = ResimResult({}, {}, method=sim.method.name,
                                  substeps=sim.substeps_setting)
        initial = sim.outputs()
        self.current = np.array([initial[name] for name in sim.output_names])
        # with sensors: the readings of the current sample, topic -> (positions, dropped)
        self.sensing = (SensedOutputs(self.contract, scene.sensors, sim.dt, len(self.current))
                        if scene.sensors else None)
        self.readings = {}
        self._sense()

    def _sense(self) -> None:
        """Read the current sample through the scene's sensors (each sample once, in order)."""
        if self.sensing is None:
            return
        values, dropped = self.sensing.bank.measure(self.sim.k, self.current)
        values, n = values.copy(), len(self.det_names)
        self.readings = {topic: (values[j * n:(j + 1) * n], dropped[j])
                         for j, topic in enumerate(self.sensing.sensed)}

    def feed(self, message) -> bool:
        """Take one logged message; False once the simulation failed (the rest is not read)."""
        name = _basename(message.topic)
        if is_truth_topic(message.topic):
            return self._output(name, message, truth=True) if name in self.fields else True
        if name in COMMAND_TOPICS:
            return self._command(name, message)
        if name in self.fields or (name == self.contract.structure_topic
                                   and self.contract.structure_names):
            return self._output(name, message)
        return True

    def _advance_to(self, k: int) -> bool:
        sim = self.sim
        while sim.k < k:
            try:
                self.current = sim.step().copy()
            except self._domain_error as exc:
                self.result.fault = str(exc)
                return False
            self.result.steps += 1
            self._sense()
        return sim.k == k

    def _reached(self, k: int) -> bool | None:
        """Return True at step k; False if the simulation failed; None if k is behind (skipped)."""
        if self._advance_to(k):
            return True
        if self.result.fault:
            return False
        self.result.skipped += 1
        return None

    def _command(self, name, message) -> bool:
        reached = self._reached(round(message.log_time / self.dt_ns))
        if not reached:
            return reached is None
        command = self.decoder.decode(name, message.data, self.sim.u.tolist())
        if command.volts is not None:   # a command the node refused is logged, not applied
            self.sim.set_input(command.volts)
        self.result.commands += 1
        return True

    def _output(self, name, message, truth: bool = False) -> bool:
        try:
            msg = decode_joint_state(message.data)
        except CdrError:
            self.result.skipped += 1
            return True
        reached = self._reached(round(msg.stamp_ns / self.dt_ns))
        if not reached:
            return reached is None
        if name in self.fields:
            names = self.det_names
            compare = [(f"{'truth/' if truth else ''}{name}.{field} ({output})", field,
                        self._expected(name, field, truth))
                       for field, output in self.fields[name].items()]
        else:
            names = list(self.contract.structure_names)
            compare = [(self.structure_key, 'position', self.contract.structure(self.current))]
        for key, field, expected in compare:
            self._compare(key, getattr(msg, field), expected, list(msg.name) == names)
        return True

    def _expected(self, name, field, truth):
        """Return a field's values as published (None: the sensor dropped the sample)."""
        if truth or field != 'position' or name not in self.readings:
            return self.contract.values(self.current, name, field)
        values, dropped = self.readings[name]
        return None if dropped else values

    def _compare(self, key, logged, expected, same_names) -> None:
        import numpy as np
        logged = np.asarray(logged, dtype=float)
        if logged.size == 0:
            return
        if expected is None or logged.shape != expected.shape or not same_names:
            deviation = math.inf   # a different channel count or order
        else:
            deviation = float(np.max(np.abs(logged - expected)))
        if math.isnan(deviation):
            deviation = math.inf
        result = self.result
        result.max_deviation[key] = max(result.max_deviation.get(key, 0.0), deviation)
        result.compared[key] = result.compared.get(key, 0) + 1


# -- offline recording (what the node does, without a ROS graph) ---------------------------------

def simulate_to_log(recorder: Recorder, sim, commands: Mapping[int, Sequence[float]] | Callable,
                    n_steps: int, joint_commands: bool = False) -> None:
    """
    Run ``sim`` for ``n_steps`` and record commands and outputs as the node does.

    ``sim`` may have any number of DETs. The bytes are the node's (joint commands name every
    DET; the structure topic when the scene has one). Needs no ROS.

    The initial state is recorded at t_0, then each step's outputs at its end time.

    :param commands: step index -> voltages, or a function k -> voltages or None, applied (and
        recorded at t_k) before the step from t_k to t_{k+1}.
    """
    import numpy as np
    get = commands if callable(commands) else commands.get
    contract = OutputContract(sim.model)
    outputs = make_outputs(contract, sim.scene, len(sim.output_names))
    t_ns = stamp_ns(sim.k, sim.dt)
    initial = np.array(list(sim.outputs().values()))
    outputs.record(recorder, t_ns, outputs.encode(sim.k, initial, t_ns))
    for _ in range(n_steps):
        k = sim.k
        volts = get(k)
        if volts is not None:
            t_ns = stamp_ns(k, sim.dt)
            volts = [float(v) for v in volts]
            if joint_commands:
                recorder.record(JOINT_COMMAND_TOPIC, encode_joint_state(contract.det_names, volts),
                                t_ns, TOPIC_TYPES[JOINT_COMMAND_TOPIC])
            else:
                recorder.record(COMMAND_TOPIC, encode_float64_multi_array(volts), t_ns,
                                TOPIC_TYPES[COMMAND_TOPIC])
            sim.set_input(volts)
        out = sim.step()
        t_ns = stamp_ns(sim.k, sim.dt)
        outputs.record(recorder, t_ns, outputs.encode(sim.k, out, t_ns))
