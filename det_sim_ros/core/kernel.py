"""
The compiled kernel's one Python facade (C, built at install time from det_sim_ros/core/_csrc).

Nothing else in the package imports ``_ckernel``.

Physics and stepping:

- ``Model(arrays)``: the model's right-hand side, outputs and stiff rates, built from the named
  fields of :class:`det_sim_ros.physics.model.ModelArrays`.
- ``Stepper(model, ...)``: a method table (det_sim_ros.sim.integrators), the charge-transient
  settings and the per-period step-count control; one count per independent coupled group.
  ``kind`` (one of ``STEPPER_KINDS``: 'stages', 'linearized', 'bdf') says how it steps and
  ``options`` holds what that kind reads (core/_csrc/stepping/kind.c); ``Stepper.kind``.
- ``matrix_phis(Z, scale, full, half)``: the phi functions of a small matrix (the dense linear
  part of 'etdrk4_linearized'; det_sim_ros.physics.matrix_phi is the same in numpy).
- status codes ``OK``, ``BAD_STRETCH``, ``NON_FINITE``, ``BAD_SLOPE`` (the model's domain) and
  ``STEP_UNDERFLOW``, ``NO_PROGRESS``, ``SINGULAR`` (the BDF stepper's failures); their text
  for users is det_sim_ros.physics.model's. A failed period leaves x at its start.
- ``Stepper.plant_nan(site, after, lasting=False)``: a NaN planted in a right-hand side or a
  BDF Jacobian, for the tests that check how a period fails.

Wire and log (the bytes of det_sim_ros.io.contract and det_sim_ros.io.log):

- ``SampleCodec``: one sample's output messages written from named fields in one call;
- ``pack_records``: MCAP Message records of consecutive samples;
- ``FrameMap``: marker frames of one-coordinate cells (det_sim_ros.ros.markers);
- ``SensorReader``: one sample's sensor readings (det_sim_ros.sim.sensors).

Every kernel object keeps its arrays in an arena of ``ARENA_SLOTS`` places; one more is a
RuntimeError, never an overflow (``keep_owned_probe(count)`` fills a fresh arena to test it).

det_sim_ros/physics/reference.py is the same physics in readable numpy; the tests hold the
compiled kernel to it on random states of every scene kind.
"""

try:
    from ._ckernel import (ARENA_SLOTS, BAD_SLOPE, BAD_STRETCH, CELL_OUTPUTS, FrameMap,
                           keep_owned_probe, matrix_phis, Model, NO_PROGRESS, NON_FINITE, OK,
                           pack_records, SampleCodec, SensorReader, SINGULAR, Stepper,
                           STEP_UNDERFLOW, STEPPER_KINDS)
except ImportError as error:  # pragma: no cover - only a broken install gets here
    raise ImportError(
        'det_sim_ros: the compiled kernel det_sim_ros.core._ckernel is missing or broken '
        f'({error}). It is built when the package is installed: `pip install .` (needs a C '
        'compiler); in a source checkout, `python setup.py build_ext --inplace`.') from None

__all__ = ['Model', 'Stepper', 'STEPPER_KINDS', 'OK', 'BAD_STRETCH', 'NON_FINITE', 'BAD_SLOPE',
           'STEP_UNDERFLOW',
           'NO_PROGRESS', 'SINGULAR', 'CELL_OUTPUTS',
           'SampleCodec', 'pack_records', 'FrameMap', 'matrix_phis', 'SensorReader',
           'ARENA_SLOTS', 'keep_owned_probe']
