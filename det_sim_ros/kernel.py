"""
The compiled kernel (C, built at install time from det_sim_ros/_csrc): status codes and the
two types everything steps with.

- ``Model(arrays)``: the model's right-hand side, outputs and stiff rates, built from the named
  fields of :class:`det_sim_ros.model.ModelArrays`.
- ``Stepper(model, ...)``: a method table (det_sim_ros.integrators), the charge-transient
  settings and the per-period step-count control; one count per independent coupled group.

det_sim_ros/reference.py is the same physics in readable numpy; the tests hold the compiled
kernel to it on random states of every scene kind.
"""

try:
    from ._ckernel import (BAD_SLOPE, BAD_STRETCH, CELL_OUTPUTS, Model, NON_FINITE, OK,
                           Stepper)
except ImportError as error:  # pragma: no cover - only a broken install gets here
    raise ImportError(
        'det_sim_ros: the compiled kernel det_sim_ros._ckernel is missing or broken '
        f'({error}). It is built when the package is installed: `pip install .` (needs a C '
        'compiler); in a source checkout, `python setup.py build_ext --inplace`.') from None

__all__ = ['Model', 'Stepper', 'OK', 'BAD_STRETCH', 'NON_FINITE', 'BAD_SLOPE', 'CELL_OUTPUTS']
