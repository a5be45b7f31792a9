"""
This checkout against another, side by side: how a bench script runs code in a source tree.

Not a benchmark. A tree is a checkout of this repository with its kernel built in place
(``python setup.py build_ext --inplace``, or ``pip install -e .`` there). Code runs in a child
process with the tree first on ``PYTHONPATH`` and the tree as its working directory (``python -c``
puts that directory first on ``sys.path``), so the child imports that tree's package whatever
the parent's venv has installed; the scripts take turns between trees within one run, so a shared
host's load hits every tree alike and their ratio holds. Used by ``controller_cost.py``,
``exact_rhs_cost.py``, ``first_sample.py``, ``stiff_speed.py``, ``realtime_switching.py`` and
``peer_processes.py``.

``THIS_TREE`` is the folder holding the package this process imports: this checkout when it is
installed editable or built in place, else the environment's installed copy (as in CI, where the
checkout holds no compiled kernel), so "this tree" always runs.
"""

from __future__ import annotations

import os
import subprocess

import det_sim_ros

THIS_TREE = os.path.dirname(os.path.dirname(os.path.abspath(det_sim_ros.__file__)))


def tree_env(tree: str, env: dict | None = None) -> dict:
    """Return ``env`` (default: this process's) with ``tree`` first on the import path."""
    return {**(os.environ if env is None else env), 'PYTHONPATH': os.path.abspath(tree)}


def run_in_tree(tree: str, argv: list, env: dict | None = None) -> str:
    """
    Run ``argv`` with ``tree``'s package; return its standard output.

    A failing child stops the script with the child's last lines of standard error (which tree
    and which command), not a bare exit status.
    """
    done = subprocess.run(argv, env=tree_env(tree, env), cwd=os.path.abspath(tree),
                          capture_output=True, text=True)
    if done.returncode:
        tail = '\n'.join(done.stderr.strip().splitlines()[-10:])
        raise SystemExit(f'in {tree}: {" ".join(argv[:3])} ... failed ({done.returncode}):\n'
                         f'{tail}')
    return done.stdout
