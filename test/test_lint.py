"""
The ROS lint checks over the package, its tests and its benchmarks.

ament_flake8 (flake8 with ament's own configuration: 99 columns, google import order, single
quotes, builtins, comprehensions, docstrings) and ament_pep257 (pydocstyle with ament's ignore
list), run as a ROS package's test_flake8.py and test_pep257.py run them. A failure lists every
offending line with its source.

The tools and the flake8 plugins ament_flake8 depends on come with the 'test' extra; nothing is
fetched at test time.
"""

from pathlib import Path
import re

import pytest

ROOT = Path(__file__).resolve().parents[1]
TREES = ('det_sim_ros', 'test', 'bench', 'docs')
LOCATION = re.compile(r'^(?P<path>[^:]+):(?P<line>\d+)')

# One violation of each kind the checks must see: import order (I100), a shadowed builtin
# (A002), a dict call (C408), double quotes (Q000), a continuation line (E128), a summary
# without a period (flake8's D400; pep257's D400, D415), a multi-line docstring whose summary
# is on its first line (pep257's D213, which ament's convention checks and flake8's does not).
PLANTED = '\n'.join([
    '"""A module planted with violations."""',
    'import sys',
    'import os',
    '',
    '',
    'def shadow(list):',
    '    """Return a dict"""',
    '    table = dict(a=1)',
    '    print(os, sys, table, list,',
    '        1)',
    '    return "quoted"',
    '',
    '',
    'def summary_first():',
    '    """Summary on the first line.',
    '',
    '    Description.',
    '    """',
    ''])
CLEAN = '\n'.join(['"""A clean module."""', '', 'VALUE = 1', ''])
FLAKE8_PLANTED = {'I100', 'A002', 'C408', 'Q000', 'E128', 'D400'}
PEP257_PLANTED = {'D400', 'D415', 'D213'}


def _with_source(report_lines):
    """Return each report line followed by the source line it points at."""
    shown = []
    for entry in report_lines:
        shown.append(entry)
        found = LOCATION.match(entry)
        if found and Path(found['path']).is_file():
            lines = Path(found['path']).read_text(encoding='utf-8').splitlines()
            number = int(found['line'])
            if 1 <= number <= len(lines):
                shown.append('    ' + lines[number - 1])
    return shown


def flake8_errors(paths):
    """Return ament_flake8's errors on ``paths`` (relative to the working directory)."""
    from ament_flake8.main import main_with_errors
    _, errors = main_with_errors(argv=list(paths))
    return errors


def pep257_errors(paths, capsys):
    """Return ament_pep257's errors on ``paths`` (it reports them on stderr)."""
    from ament_pep257.main import main
    capsys.readouterr()
    main(argv=list(paths))
    return [line for line in capsys.readouterr().err.splitlines() if LOCATION.match(line)]


def _codes(errors):
    """Collect the first error code of each report line."""
    return {re.search(r'\b[A-Z]\d{3}\b', error)[0] for error in errors}


@pytest.mark.parametrize('tree', TREES)
def test_flake8(tree, monkeypatch):
    monkeypatch.chdir(ROOT)   # ament_flake8 walks the working directory for AMENT_IGNORE
    errors = flake8_errors([tree])
    assert not errors, (f'ament_flake8: {len(errors)} errors in {tree}/\n'
                        + '\n'.join(_with_source(errors)))


@pytest.mark.parametrize('tree', TREES)
def test_pep257(tree, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    errors = pep257_errors([tree], capsys)
    assert not errors, (f'ament_pep257: {len(errors)} errors in {tree}/\n'
                        + '\n'.join(_with_source(errors)))


def test_the_checks_see_planted_violations(tmp_path, monkeypatch, capsys):
    (tmp_path / 'planted.py').write_text(PLANTED, encoding='utf-8')
    (tmp_path / 'clean.py').write_text(CLEAN, encoding='utf-8')
    monkeypatch.chdir(tmp_path)
    assert FLAKE8_PLANTED <= _codes(flake8_errors(['planted.py']))
    assert PEP257_PLANTED <= _codes(pep257_errors(['planted.py'], capsys))
    assert flake8_errors(['clean.py']) == []
    assert pep257_errors(['clean.py'], capsys) == []


def test_no_test_asserts_inside_a_finally_block():
    """An assert in ``finally`` replaces the error that got there: the first failure is lost."""
    import ast
    found = []
    for path in sorted((ROOT / 'test').glob('*.py')):
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
            if isinstance(node, ast.Try):
                found += [f'{path.name}:{sub.lineno}' for stmt in node.finalbody
                          for sub in ast.walk(stmt) if isinstance(sub, ast.Assert)]
    assert not found, found
