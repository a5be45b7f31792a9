"""
The node's command intake: decode, check, log and hold voltage commands.

A voltage command's CDR bytes are decoded and checked by the topic contract
(det_sim_ros.io.contract), logged at the period they apply to, and held by the simulator
until the next command; refused and clamped ones are counted and warned about.
"""

from __future__ import annotations

from typing import Callable

from .diagnostics import CommandCounts
from ..io.contract import clamp_message, CommandDecoder, JOINT_COMMAND_TOPIC, stamp_ns, TOPIC_TYPES

__all__ = ['CommandInput']


class CommandInput:
    """
    Applies commands to a simulator and counts them.

    The counters: ``received``, ``refused``, ``clamped``, ``last_refused`` (the latest
    refusal's reason), ``last_clamped`` (the latest clamp's warning).

    :param names: the DETs in command order.
    :param v_max: the largest voltage, V (beyond it a command is clamped).
    :param recorder: the MCAP recorder the commands are logged to, or None.
    :param on_command: called with every decoded command (applied or refused).
    """

    def __init__(self, simulator, names, v_max: float, recorder, logger,
                 on_command: Callable):
        self._sim = simulator
        self._decoder = CommandDecoder(names, v_max)
        self._v_max = v_max
        self._recorder = recorder
        self._logger = logger
        self._on_command = on_command
        self.received = 0
        self.refused = 0
        self.clamped = 0
        self.last_refused = ''
        self.last_clamped = ''

    def counts(self) -> CommandCounts:
        """Return the counters now."""
        return CommandCounts(self.received, self.refused, self.clamped, self.last_refused)

    def apply(self, topic: str, data: bytes) -> None:
        """Decode, check, log (at the period it applies to) and hold a command's CDR bytes."""
        self.received += 1
        sim = self._sim
        command = self._decoder.decode(topic, data, sim.u)
        if self._recorder is not None and command.canonical:
            self._recorder.record(topic, command.canonical, stamp_ns(sim.k, sim.dt),
                                  TOPIC_TYPES[topic])
        if command.volts is None:
            self._refuse(command.reason + ('' if command.reason.startswith(
                JOINT_COMMAND_TOPIC + ':') else '; holding the previous voltages'))
        else:
            check = sim.set_input(command.volts)
            if not check.accepted:   # the contract's checks are the simulator's; not expected
                self._refuse(f'{topic}: {check.reason}; holding the previous voltages')
            elif command.clamped:
                self.clamped += 1
                self.last_clamped = clamp_message(topic, command.clamped, self._v_max)
                self._logger.warning(self.last_clamped, throttle_duration_sec=1.0)
        self._on_command(command)

    def refuse(self, reason: str) -> None:
        """Count a command that could not be read as a message (a live client's bad JSON)."""
        self.received += 1
        self._refuse(f'{reason}; holding the previous voltages')

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        self.last_refused = reason
        self._logger.warning(f'command refused: {reason}', throttle_duration_sec=1.0)
