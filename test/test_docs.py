"""
Checks on the documentation.

The parameter reference is the node's table, the README stays a short user guide, and every
relative link in README.md and docs/ points at a file that exists. The pages tell no development
story, and the package's comments (Python comments and docstrings, C comments) carry neither a
measured figure nor dated history: a number a script measures lives in the docs, with its date,
commit and bench command, and a comment points there.
"""

import ast
import collections
import importlib.util
import io
import os
import re
import tokenize

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


# a commit hash: 7 to 40 hex digits, at least one of them a digit
_HASH = r'(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b'
# dated history on a page: what an older commit measured told as the past ('At <commit>,
# before ...', 'against 65 % at <commit>'), a measurement dated by a feature ('before BDF'),
# the words of a story; a table's own provenance ('Measured <date>, commit <hash>') and a side
# by side of two commits are not history
_PAGE_HISTORY = re.compile(r'\b(?:this|last|next|a later) session|\bissue [0-9]+'
                           r'|\b(?:formerly|previously|until now|used to (?:cost|be|take))\b'
                           r'|\bbefore (?:BDF|this change|the change)\b'
                           rf'|\b[Aa]t {_HASH}, before\b|% at {_HASH}', re.IGNORECASE)


@pytest.mark.parametrize('path', _pages(), ids=os.path.basename)
def test_pages_tell_no_development_story(path):
    assert not [m.group(0) for m in _PAGE_HISTORY.finditer(_read(path))]


def test_the_page_history_check_sees_planted_stories():
    for text in ('At 3b71650, before BDF, the default read 0.78 %.', 'as in this session',
                 'against 65 % at 7a29fd1', 'it previously took 3 steps'):
        assert _PAGE_HISTORY.search(text), text
    for text in ('Measured 2026-12-02, commit 3a20630, 2-core x86-64 VM',
                 'on 2026-12-03 at 2d10f65, 2-core x86-64 VM',
                 '--tree <f137f46> --tree <3b71650>'):
        assert not _PAGE_HISTORY.search(text), text


# -- the package's comments: why, not measured figures or history -------------------------------

PACKAGE = os.path.join(ROOT, 'det_sim_ros')
_N = r'(?<![\w.])~?\d+(?:\.\d+)?(?:e[-+]?\d+)?(?:\s?[–-]\s?\d+(?:\.\d+)?)?'
# a measured figure: a cost in (sub-)microseconds or ms per operation, a speed ratio ('3x'),
# a percentage gained or lost, a size in bytes; a setting's own value ('1 kHz', '0 V', '5 s')
# is not one
_FIGURE = re.compile('|'.join([
    _N + r'\s?(?:ns|us|µs)\b',
    _N + r'[x×](?=[\s,.;:)]|$)',
    _N + r'\s?% (?:less|more|faster|slower|cheaper|of the (?:node|kernel|time|CPU))',
    _N + r'\s?(?:kB|KiB|MB|MiB|GB)\b',
    _N + r'\s?ms (?:per|a|each|of CPU)\b']))
_COMMENT_HISTORY = re.compile(r'\b(?:formerly|previously|until now|used to (?:cost|be|take)'
                              r'|was measured|were measured|in Python (?:that|a sample|it) cost)\b'
                              rf'|\b(?:at|since|until|before|after) (?:commit )?{_HASH}'
                              r'|\b20[0-9]{2}-[0-9]{2}-[0-9]{2}\b', re.IGNORECASE)
# (file, figure) -> why it is not a measurement: constants of physics, of a protocol, a design
ALLOWED_FIGURES = {
    ('ros/pacing/__init__.py', '1 us'): "the free-run timer's period, a setting",
    ('ros/pacing/free_run.py', '1 us'): "the free-run timer's period, a setting",
    ('io/log/recorder.py', '64 KiB'): "mcap's default chunk size, a constant of the library",
    ('analysis/benchmark.py', '1 ns'): 'the offset a zero-order hold is built with, a setting',
}
# Files another change is rewriting at the same time; their figures move to the docs with it
# (the lead's list). Remove a file from here when its comments are clean.
NOT_YET_CHECKED = set()


def _python_comments(source: str):
    """Yield (line, text) of every comment and docstring of a Python module."""
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            yield token.start[0], token.string
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            text = ast.get_docstring(node, clean=False)
            if text:
                for i, line in enumerate(text.split('\n')):
                    yield node.body[0].lineno + i, line


def _c_comments(source: str):
    """Yield (line, text) of every line of every comment of a C file."""
    for match in re.finditer(r'//[^\n]*|/\*.*?\*/', source, re.DOTALL):
        first = source.count('\n', 0, match.start()) + 1
        for i, line in enumerate(match.group().split('\n')):
            yield first + i, line


def _comment_findings(pattern, allowed=()):
    """Return 'file:line: match' for every comment line of the package that ``pattern`` finds."""
    found = []
    for folder, _, names in os.walk(PACKAGE):
        for name in sorted(names):
            path = os.path.join(folder, name)
            rel = os.path.relpath(path, PACKAGE).replace(os.sep, '/')
            if rel in NOT_YET_CHECKED or not name.endswith(('.py', '.c', '.h')):
                continue
            source = _read(path)
            lines = _python_comments(source) if name.endswith('.py') else _c_comments(source)
            for line, text in lines:
                found += [f'{rel}:{line}: {m.group(0)}' for m in pattern.finditer(text)
                          if (rel, m.group(0)) not in allowed]
    return found


def test_comments_carry_no_measured_figure():
    """A figure a script measures belongs in the docs; the comment links the section."""
    found = _comment_findings(_FIGURE, ALLOWED_FIGURES)
    assert not found, ('measured figures in comments (move them to the docs with their date, '
                       f'commit and bench command; link the section): {found}')


def test_comments_tell_no_history():
    found = _comment_findings(_COMMENT_HISTORY)
    assert not found, f'history in comments (say why, not what happened when): {found}'


def test_the_comment_checks_see_planted_figures_and_history():
    for text in ('costs ~3 us per sample', '1.5x faster', '8 % less time', 'a DATA(p) of ~0.5 kB',
                 '~2 ms per poll', '77 -> 22 us'):
        assert _FIGURE.search(text), text
    for text in ('at 1 kHz', 'from 0 V to 3 kV', 'after 5 s', 'a 2 x 2 block', 'n_r 7, 3e-3'):
        assert not _FIGURE.search(text), text
    for text in ('in Python a sample cost the node', 'at commit 3a20630', 'since 7a29fd1',
                 'measured 2026-12-03', 'it previously took'):
        assert _COMMENT_HISTORY.search(text), text
    assert not _COMMENT_HISTORY.search('no longer vouched for; before the first period')
    assert set(ALLOWED_FIGURES) and all(os.path.exists(os.path.join(PACKAGE, f))
                                        for f, _ in ALLOWED_FIGURES)
    assert all(os.path.exists(os.path.join(PACKAGE, f)) for f in NOT_YET_CHECKED)


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


# -- measured tables: each says when, on which code and by which command -----------------------

MEASURED_PAGES = ('performance.md', 'fidelity.md', 'work_precision.md')
_DATE = re.compile(r'\b20\d\d-[01]\d-[0-3]\d\b')
_COMMIT = re.compile(rf'(?<![\w-]){_HASH}')
# the command that regenerates a table: `python bench/<script>.py ...` (behind flock and env as
# the page gives it) or `det_sim <verb> ...`, in backticks
_COMMAND = re.compile(r'`[^`\n]*(?:\bpython bench/\w+\.py|\bdet_sim [a-z])[^`\n]*`')


def _tables_without_provenance(text: str):
    """
    Return the first row of every table not preceded, within its section, by a provenance.

    A provenance is a paragraph (lines up to a blank line) naming a date (YYYY-MM-DD), a commit
    hash and the bench command. A section runs from its heading to the next heading of its
    level or higher; a subsection's tables may be dated by its parent's text above it.
    """
    text = re.sub(r'```.*?```', '', text, flags=re.DOTALL)   # a code block's '#' is no heading
    missing = []
    sections = [(0, [])]   # (heading level, its paragraphs so far, each joined into one line)
    lines = text.splitlines() + ['']
    current = []
    in_table = False
    for i, line in enumerate(lines):
        stripped = line.strip()
        heading = re.match(r'(#+)\s', stripped)
        if heading:
            if current:
                sections[-1][1].append(' '.join(current))
            level = len(heading.group(1))
            while sections[-1][0] >= level:
                sections.pop()
            sections.append((level, []))
            current, in_table = [], False
            continue
        # a subsection inherits its parents' text, but not the page title's (the page's intro)
        paragraphs = [p for k, (level, section) in enumerate(sections)
                      if level >= 2 or k == len(sections) - 1 for p in section]
        is_row = stripped.startswith('|')
        if is_row and not in_table and i + 1 < len(lines) \
                and re.match(r'\|\s*:?-{3,}', lines[i + 1].strip()):
            if current:   # the paragraph just above the table, if not yet closed
                sections[-1][1].append(' '.join(current))
                paragraphs.append(' '.join(current))
                current = []
            if not any(_DATE.search(p) and _COMMIT.search(p) and _COMMAND.search(p)
                       for p in paragraphs):
                missing.append(stripped)
            in_table = True
            continue
        if is_row and in_table:
            continue
        in_table = False
        if stripped:
            current.append(stripped)
        elif current:
            sections[-1][1].append(' '.join(current))
            current = []
    return missing


@pytest.mark.parametrize('name', MEASURED_PAGES)
def test_every_measured_table_says_date_commit_and_command(name):
    """Check that each table of a measured page is dated, has its commit and its command."""
    missing = _tables_without_provenance(_read(os.path.join(DOCS, name)))
    assert not missing, f'docs/{name}: tables without date, commit and command: {missing}'


def test_the_table_provenance_check_sees_a_bare_table():
    table = '| a | b |\n|---|---|\n| 1 | 2 |\n'
    dated = ('Measured 2026-12-06, commit 1a21759, 2-core x86-64 VM, by '
             '`flock /tmp/lock python bench/realtime.py --quick`:\n\n')
    assert _tables_without_provenance('## A\n\n' + dated + table) == []
    assert _tables_without_provenance('## A\n\n' + dated + table + '\nMore.\n\n' + table) == []
    for undated in (dated.replace('2026-12-06', 'today'), dated.replace('1a21759', 'main'),
                    dated.replace('python bench/realtime.py', 'the bench')):
        assert _tables_without_provenance('## A\n\n' + undated + table) == ['| a | b |']
    # a provenance in the section before does not date this one, its parent's text does
    assert _tables_without_provenance('## A\n\n' + dated + '## B\n\n' + table) == ['| a | b |']
    assert _tables_without_provenance('## A\n\n' + dated + '### B\n\n' + table) == []
    assert _tables_without_provenance(
        '## A\n\n### B\n\n' + dated + '### C\n\n' + table) == ['| a | b |']
    assert _tables_without_provenance('# Page\n\n' + dated + table) == []
    assert _tables_without_provenance('# Page\n\n' + dated + '## A\n\n' + table) == ['| a | b |']
    assert _tables_without_provenance('## A\n\n' + table + '\n' + dated) == ['| a | b |']
