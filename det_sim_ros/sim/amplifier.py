"""
The amplifier's command side: DAC quantization, transport delay and output offset, per period.

The command a controller holds for period k reaches the supply circuit as

    applied_k = Q(command_{k - d}) + offset,  Q(v) = rint(v / lsb) lsb,  lsb = v_max / (2^bits - 1)

per DET (d its delay in whole control periods; before the first command the delay line holds
the scene's initial voltage, 0 V). The amplifier's bandwidth, slew rate and current limit act
inside the supply circuit (the compiled kernel), not here. :class:`~.simulator.Simulator` (and
so the node, ``simulate`` and a log's re-simulation) runs every command through one
:class:`CommandStage`, a period at a time or a whole run at once, with the same arithmetic.
"""

from __future__ import annotations

import collections

import numpy as np

__all__ = ['CommandStage']


class CommandStage:
    """The DAC, delay and offset of every DET's command (one instance per simulator)."""

    def __init__(self, amplifiers, v_max, dt: float):
        v_max = np.broadcast_to(np.asarray(v_max, dtype=float), (len(amplifiers),))
        self.lsb = np.array([v / (2.0 ** amp.dac_bits - 1.0) if amp.dac_bits else 0.0
                             for amp, v in zip(amplifiers, v_max)])
        self._quantized = bool(np.any(self.lsb > 0.0))
        self._safe_lsb = np.where(self.lsb > 0.0, self.lsb, 1.0)
        self.offset = np.array([amp.offset for amp in amplifiers], dtype=float)
        self.delays = np.array([amp.delay_periods(dt) for amp in amplifiers], dtype=np.int64)
        self._depth = int(self.delays.max(initial=0))
        # per DET, for one period at a time in plain floats (a numpy round trip costs tens of
        # microseconds, more than the period's physics): the same operations as _shape
        self._per_det = list(zip(self.lsb.tolist(), self.offset.tolist(),
                                 (self._depth - self.delays).tolist()))
        self.reset()

    @classmethod
    def for_scene(cls, scene) -> 'CommandStage | None':
        """Return the scene's stage, or None when no DET's DAC, delay or offset is on."""
        amplifiers = scene.cell_amplifiers()
        if not any(amp.acts_on_command for amp in amplifiers):
            return None
        v_max = [physics.v_max for physics in scene.cell_physics()]
        return cls(amplifiers, v_max, scene.dt)

    def reset(self) -> None:
        """Empty the delay line: it holds the initial voltage, 0 V."""
        zeros = [0.0] * len(self.delays)
        self._line = collections.deque([zeros] * self._depth, maxlen=self._depth or None)
        self._forget_held()

    def _forget_held(self) -> None:
        self._held, self._held_periods, self._held_applied = None, 0, None

    def _shape(self, commands: np.ndarray) -> np.ndarray:
        """Return the DAC's levels of ``commands`` plus the offset (rows: periods)."""
        if self._quantized:
            levels = np.rint(commands / self._safe_lsb) * self._safe_lsb
            commands = np.where(self.lsb > 0.0, levels, commands)
        return commands + self.offset

    def run(self, commands) -> np.ndarray:
        """
        Return the applied inputs of consecutive periods (rows) given their held commands.

        The delay line moves on by as many periods; one row at a time gives the same result.
        """
        commands = np.asarray(commands, dtype=float).reshape(-1, len(self.delays))
        n, depth = len(commands), self._depth
        if depth:
            past = np.array(list(self._line), dtype=float).reshape(depth, len(self.delays))
            line = np.vstack([past, commands])
            rows = (depth - self.delays)[None, :] + np.arange(n)[:, None]
            delayed = np.take_along_axis(line, rows, axis=0)
            self._line.extend(line[len(line) - depth:].tolist())
            self._forget_held()
        else:
            delayed = commands
        return self._shape(delayed)

    def apply(self, command) -> np.ndarray:
        """Return the applied input of the next period given its held command."""
        row = (command.tolist() if type(command) is np.ndarray and command.dtype == np.float64
               else [float(v) for v in command])
        if row == self._held:
            self._held_periods += 1
        else:
            self._held, self._held_periods, self._held_applied = row, 1, None
        if self._held_applied is not None:   # the line holds this command only: the same input
            if self._depth:
                self._line.append(row)
            return self._held_applied.copy()
        line = list(self._line) + [row] if self._depth else [row]
        applied = []
        for i, (lsb, offset, back) in enumerate(self._per_det):
            v = line[back][i]
            if lsb > 0.0:
                v = float(round(v / lsb)) * lsb
            applied.append(v + offset)
        if self._depth:
            self._line.append(row)
        applied = np.array(applied)
        if self._held_periods > self._depth:   # held for the whole line: kept for the next
            self._held_applied = applied.copy()
        return applied
