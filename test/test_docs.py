"""
Checks on the documentation.

The parameter reference is the node's table, the README stays a short user guide, and every
relative link in README.md and docs/ points at a file that exists.
"""

import collections
import importlib.util
import os
import re

import pytest

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')
DOCS = os.path.join(ROOT, 'docs')


def _generator():
    spec = importlib.util.spec_from_file_location(
        'generate_parameters', os.path.join(DOCS, 'generate_parameters.py'))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _read(path):
    with open(path, encoding='utf-8') as f:
        return f.read()


def _pages():
    names = sorted(n for n in os.listdir(DOCS) if n.endswith('.md'))
    return [os.path.join(ROOT, 'README.md')] + [os.path.join(DOCS, n) for n in names]


def test_parameter_page_is_generated_from_the_node_table():
    """
    Check that docs/parameters.md is what the generator makes of the node's table.

    The page must equal the generator's rendering of the current NODE_PARAMS: a changed
    default, range or description without a regenerated page fails here.
    """
    generator = _generator()
    assert _read(generator.PAGE) == generator.render(), (
        'docs/parameters.md is out of date: run python docs/generate_parameters.py')


def test_every_node_parameter_has_a_row_with_its_default():
    from det_sim_ros.ros.params import NODE_PARAMS
    page = _read(_generator().PAGE)
    for name, (default, _description, read_only, _bounds) in NODE_PARAMS.items():
        line = next((row for row in page.splitlines() if row.startswith(f'| `{name}` |')), None)
        assert line is not None, f'no row for {name}'
        assert f'| {"no" if read_only else "yes"} |' in line


def test_named_tuple_entries_render_like_plain_tuples():
    """
    Check that a table of named tuples renders like one of plain tuples.

    Entries are read by unpacking, so a table of named tuples with the same four fields in the
    same order gives the same page.
    """
    from det_sim_ros.ros.params import NODE_PARAMS
    Entry = collections.namedtuple('Entry', 'default description read_only bounds')
    named = {name: Entry(*entry) for name, entry in NODE_PARAMS.items()}
    generator = _generator()
    assert generator.render(named) == generator.render(NODE_PARAMS)


def test_rows_show_type_range_choices_and_runtime():
    generator = _generator()
    assert generator.row('a', (0.05, 'x | y', False, (0.0, 3600.0))) == (
        '| `a` | double | `0.05` | [0, 3600] | yes | x \\| y |')
    assert generator.row('b', ('zstd', 'codec', True, ('zstd', 'lz4'))) == (
        "| `b` | string | `'zstd'` | `zstd`, `lz4` | no | codec |")
    assert generator.row('c', (True, 'on', True, None)) == '| `c` | bool | `true` |  | no | on |'


def test_readme_is_a_short_user_guide():
    assert len(_read(os.path.join(ROOT, 'README.md')).splitlines()) <= 200


@pytest.mark.parametrize('path', _pages(), ids=os.path.basename)
def test_pages_tell_no_development_story(path):
    narrative = re.compile(r'\b(this|last|next|a later) session|\bissue [0-9]+', re.IGNORECASE)
    assert not [m.group(0) for m in narrative.finditer(_read(path))]


@pytest.mark.parametrize('path', _pages(), ids=os.path.basename)
def test_relative_links_point_at_files(path):
    text = re.sub(r'```.*?```', '', _read(path), flags=re.DOTALL)
    targets = re.findall(r'\]\(([^)\s]+)\)', text)
    base = os.path.dirname(path)
    missing = [t for t in targets if not re.match(r'[a-z]+:', t)
               and not os.path.exists(os.path.join(base, t.split('#')[0]))]
    assert not missing, f'{os.path.basename(path)}: links to missing files {missing}'


def test_the_shell_page_covers_every_verb():
    """Check that docs/shell.md shows every verb of det_sim's parser as `det_sim VERB`."""
    from det_sim_ros.cli.det_sim import VERBS
    text = _read(os.path.join(DOCS, 'shell.md'))
    missing = [verb for verb in VERBS if not re.search(rf'`det_sim {verb}\b', text)]
    assert not missing, f'docs/shell.md does not cover: {missing}'
