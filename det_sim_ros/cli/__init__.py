"""
Command-line entry points: ``det_sim`` (:func:`main`, one command with its verbs),
``sim_node`` (:mod:`.sim_node`) and ``det_sim_replay``. Nothing heavy is imported until a
command runs.
"""


def main(argv=None) -> int:
    """``det_sim``: parse ``argv`` (default: the command line) and run its verb."""
    from .det_sim import main as run
    return run(argv)
