"""
Synthetic measurements from known parameters.

The fit's own check, and a way to see what a planned experiment can identify before running it
on a rig.

:func:`step_and_sine` is a command that excites the beam's mode (a step up and down) and the
slow creep and the quasi-static gain (a slow sine after it); :func:`synthetic_measurement` runs
it through a scene and adds Gaussian noise to Δy at a fraction of the stroke.
"""

from __future__ import annotations

import numpy as np

from .measurement import Channel, Measurement

__all__ = ['step_and_sine', 'synthetic_measurement']


def step_and_sine(t_end: float, dt: float, step_volts: float = 2000.0,
                  sine_mean: float = 1200.0, sine_amplitude: float = 800.0,
                  sine_hz: float = 1.5) -> np.ndarray:
    """
    Return per-period voltages (V): 0 V, a step over the first quarter, then a sine.

    The step is on from 5 % to 25 % of ``t_end``; the sine starts at 35 %.
    """
    t = np.arange(int(round(t_end / dt))) * dt
    volts = np.where((t >= 0.05 * t_end) & (t < 0.25 * t_end), step_volts, 0.0)
    sine = t >= 0.35 * t_end
    volts[sine] = sine_mean + sine_amplitude * np.sin(2 * np.pi * sine_hz
                                                      * (t[sine] - 0.35 * t_end))
    return volts


def synthetic_measurement(scene, volts, noise: float = 0.01, seed: int = 0,
                          channels=('dy',), source: str = 'synthetic') -> Measurement:
    """
    Run ``volts`` through ``scene`` and return its channels as a measurement.

    ``noise``: Gaussian noise on Δy with a standard deviation of this fraction of the stroke
    (the range of Δy); charge and current are noise-free.
    """
    from ..io.contract import rest_shortenings
    from ..sim.simulator import simulate, Simulator
    from .measurement import CHANNELS
    sim = Simulator(scene)
    volts = np.asarray(volts, dtype=float).reshape(len(volts), -1)
    run = simulate(sim, volts, len(volts) * sim.dt)
    rng = np.random.default_rng(seed)
    measured = {}
    for name in channels:
        output, relative = CHANNELS[name]
        values = np.column_stack([run.outputs[sim.output_names[i]]
                                  for i in sim.model.channel(output)])
        if relative:
            values = np.asarray(rest_shortenings(scene)) - values
            values = values + rng.normal(0.0, noise * np.ptp(values), values.shape)
        measured[name] = Channel(name, np.arange(len(values)), values)
    return Measurement(source, sim.dt, volts, measured, scene)
