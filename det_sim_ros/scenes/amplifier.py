"""
The high-voltage amplifier between the voltage command and each DET: its knobs and their checks.

The scene's optional ``amplifier:`` section (keys in ``AMPLIFIER_SPEC``) applies to every DET;
``dets.<name>`` may override any of its keys for one DET. Every knob is off by default (an
ideal source: the command reaches the supply circuit at once and exactly).

Where each knob acts: the DAC, the offset and the delay act on the command, once per control
period (det_sim_ros.sim.amplifier); the bandwidth, the slew rate and the current limit act inside
the supply circuit's dynamics (the compiled kernel). Units: V, A, Hz, s.
"""

from __future__ import annotations

import dataclasses
import math

from .keys import AMPLIFIER_DEFAULTS, AMPLIFIER_SPEC, check_section, SceneError

__all__ = ['Amplifier', 'check_amplifier_section', 'check_amplifiers', 'IDEAL']

# delay * rate_hz may differ from a whole number by this much (a delay written in decimal)
_WHOLE_PERIODS = 1e-9


@dataclasses.dataclass(frozen=True)
class Amplifier:
    """One DET's amplifier (SI units; 0 switches a knob off, see ``AMPLIFIER_SPEC``)."""

    slew_rate: float = 0.0
    current_limit: float = 0.0
    bandwidth: float = 0.0
    dac_bits: int = 0
    delay: float = 0.0
    offset: float = 0.0

    @property
    def acts_on_command(self) -> bool:
        """Return True if the DAC, the delay or the offset change the command."""
        return self.dac_bits > 0 or self.delay > 0.0 or self.offset != 0.0

    @property
    def acts_in_circuit(self) -> bool:
        """Return True if the bandwidth, slew rate or current limit shape the supply."""
        return self.slew_rate > 0.0 or self.current_limit > 0.0 or self.bandwidth > 0.0

    @property
    def has_output_state(self) -> bool:
        """Return True if the output voltage v_a lags the command (bandwidth or slew rate)."""
        return self.slew_rate > 0.0 or self.bandwidth > 0.0

    @property
    def time_constant(self) -> float:
        """Return the output's first-order time constant 1/(2 pi bandwidth), s (0: ideal)."""
        return 1.0 / (2.0 * math.pi * self.bandwidth) if self.bandwidth > 0.0 else 0.0

    def delay_periods(self, dt: float) -> int:
        """Return the delay in whole control periods of ``dt`` seconds."""
        return int(round(self.delay / dt))


IDEAL = Amplifier()


def check_amplifier_section(content, where: str = 'amplifier') -> dict:
    """Return the section's values checked, missing keys at their defaults (all off)."""
    return check_section(where, content, AMPLIFIER_SPEC, AMPLIFIER_DEFAULTS)


def check_amplifiers(scene) -> None:
    """
    Check what spans the amplifier and the rest of the scene, one line per problem.

    A delay that is not a whole number of control periods, circuit knobs without the RC supply
    circuit they act in, and a current limit below the leakage current v_max / Rp (the
    amplifier could not even hold the DET at v_max).
    """
    for name, amp, physics in zip(scene.det_names, scene.cell_amplifiers(),
                                  scene.cell_physics()):
        periods = amp.delay * scene.rate_hz
        if abs(periods - round(periods)) > _WHOLE_PERIODS * max(1.0, periods):
            raise SceneError(f"DET {name!r}: scene key 'amplifier.delay' must be a whole number "
                             f'of control periods of {scene.dt:g} s (got {amp.delay!r} s = '
                             f'{periods:g} periods)')
        if amp.acts_in_circuit and scene.source != 'rc':
            raise SceneError(f"DET {name!r}: the amplifier's slew_rate, current_limit and "
                             'bandwidth act in the RC supply circuit: they need scene.source '
                             f"'rc' (got {scene.source!r})")
        leakage = physics.v_max / physics.Rp
        if 0.0 < amp.current_limit <= leakage:
            raise SceneError(f"DET {name!r}: scene key 'amplifier.current_limit' "
                             f'{amp.current_limit:g} A cannot hold the leakage current v_max/Rp '
                             f'= {leakage:g} A')
