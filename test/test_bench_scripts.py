"""
Every bench/ script runs on today's code: each one's ``--quick`` mode, as a user starts it.

The scripts measure, they assert nothing about their numbers; this checks only that each one
still starts, runs to its end and exits 0 on the package as installed, so a script that rots (a
function renamed, a scene key gone, a check of a model the default no longer is) fails here
rather than in a maintainer's hands months later. A quick mode is the script's own code path on
a small case (seconds); it never writes into the repository (checked: the stored data, the
docs and their figures are left untouched).

Every script runs as its own process, so every test here carries the ``ros`` mark
(test/conftest.py: a test that starts a process), whether or not the script starts nodes.
"""

import os
import subprocess
import sys

from conftest import child_env
import pytest

pytestmark = pytest.mark.ros

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BENCH = os.path.join(ROOT, 'bench')
# modules the scripts import, not scripts (bench/README.md, Tools)
HELPERS = {'checkouts.py', 'peer_processes.py'}
SCRIPTS = sorted(name for name in os.listdir(BENCH)
                 if name.endswith('.py') and name not in HELPERS)
# what a quick run must leave as it was: stored results, docs, figures
KEPT = ('bench/data', 'docs')


def _fingerprint() -> dict:
    """Return path -> (size, modification time) of every file under KEPT."""
    prints = {}
    for top in KEPT:
        for folder, _, names in os.walk(os.path.join(ROOT, top)):
            for name in names:
                stat = os.stat(os.path.join(folder, name))
                prints[os.path.relpath(os.path.join(folder, name), ROOT)] = (stat.st_size,
                                                                             stat.st_mtime_ns)
    return prints


def test_the_helpers_listed_exist():
    """A helper renamed or removed must leave this list too, or a script would go unrun."""
    assert HELPERS <= set(os.listdir(BENCH))
    assert len(SCRIPTS) >= 30   # the folder was found and holds the scripts


@pytest.mark.parametrize('name', SCRIPTS)
def test_bench_script_runs_in_its_quick_mode(name, tmp_path):
    """
    ``python bench/<name> --quick`` exits 0, prints its numbers and writes nothing into the repo.

    The child imports the package this test imports (child_env's PYTHONPATH); without
    PYTHONSAFEPATH, as a user runs it, so the script's folder is first on its path and the
    scripts' imports of each other work. The timeout is a safety net only.
    """
    before = _fingerprint()
    env = child_env()
    env.pop('PYTHONSAFEPATH', None)
    done = subprocess.run([sys.executable, os.path.join(BENCH, name), '--quick'], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=300)
    output = (done.stdout + done.stderr)[-3000:]
    assert done.returncode == 0, f'bench/{name} --quick failed:\n{output}'
    assert done.stdout.strip(), f'bench/{name} --quick printed nothing:\n{output}'
    assert _fingerprint() == before, f'bench/{name} --quick changed files in the repository'
