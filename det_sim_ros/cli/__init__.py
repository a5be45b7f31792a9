"""
Command-line entry points: ``det_sim``, ``det_sim_replay`` and ``sim_node``.

``det_sim`` (:func:`main`) is one command with its verbs, one module each in :mod:`.verbs`;
``det_sim_replay`` (:func:`main_replay`) is the ``replay`` verb on its own; ``sim_node`` is
:mod:`.sim_node`. Nothing heavy is imported until a command runs.
"""


def main(argv=None) -> int:
    """``det_sim``: parse ``argv`` (default: the command line) and run its verb."""
    from .det_sim import main as run
    return run(argv)


def main_replay(argv=None) -> int:
    """``det_sim_replay``: parse ``argv`` (default: the command line) and run it."""
    from .det_sim import main_replay as run
    return run(argv)
