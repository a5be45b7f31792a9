"""
The verbs of ``det_sim``, one module each.

A verb module has ``HELP``, optionally ``DESCRIPTION``, ``add_arguments(parser)`` and
``main(args) -> exit code`` (det_sim_ros.cli.det_sim lists them).
"""
