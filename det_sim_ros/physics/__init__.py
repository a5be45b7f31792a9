"""
The physics of the buckled-beam actuators.

Ritz shapes, energies -> model, statics, linearization, geometry and the numpy reference of the
compiled right-hand side.
"""
