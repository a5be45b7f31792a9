"""Time stepping: the simulator on the grid t = k dt with inputs held per period, and the
integration methods as coefficient tables (:mod:`.integrators`)."""
