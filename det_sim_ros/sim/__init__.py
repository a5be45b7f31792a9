"""
Time stepping: the simulator and the integration methods.

The simulator steps on the grid t = k dt with inputs held per period; the integration methods
are coefficient tables (:mod:`.integrators`).
"""
