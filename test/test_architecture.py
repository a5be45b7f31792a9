"""
docs/architecture.md, the maintainer's map, against the tree it maps.

The page names files by path (package-relative, or from the repository root for bench/, test/,
docs/, config/): each must exist, so a module renamed or removed fails here until the map
follows. Every layer folder and every C folder has its row; every module of the concepts that
span layers (sensors, replay) is named with its role; the where-to-change table keeps its
tasks; the README and the development guide link the page.
"""

import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# the source tree, not the installed package: an install holds no C sources
PACKAGE = os.path.join(ROOT, 'det_sim_ros')
PAGE = os.path.join(ROOT, 'docs', 'architecture.md')
REPO_TOPS = ('bench/', 'test/', 'docs/', 'config/')
# what a path looks like on the page: a file with an extension, or a folder ending in '/'
PATH = re.compile(r'`([A-Za-z_][\w./-]*(?:\.(?:py|c|h|yaml|md)|/))`')
# the modules of one concept spread over layers (their stems): each needs a row on the page
CONCEPT_STEMS = ('sensors', 'sensing', 'replay', 'play')
TASKS = ('publishes displacement', 'log file naming', 'stepper that is a coefficient table',
         'stepper that is not a table', 'sensor model', 'Replay of a log', 'Add a scene key',
         'Add an output')


def _page() -> str:
    with open(PAGE, encoding='utf-8') as stream:
        return stream.read()


def _resolve(path: str) -> str:
    """Return the file or folder a path on the page names (from the repo root or the package)."""
    if path.startswith(REPO_TOPS + ('det_sim_ros/',)):
        return os.path.join(ROOT, path)
    return os.path.join(PACKAGE, path)


def test_every_path_the_page_names_exists():
    paths = set(PATH.findall(_page()))
    assert len(paths) > 50   # the pattern still finds the page's paths
    missing = sorted(p for p in paths if not os.path.exists(_resolve(p)))
    assert not missing, f'docs/architecture.md names paths that do not exist: {missing}'


def test_every_layer_and_every_kernel_folder_has_a_row():
    page = _page()
    layers = sorted(name for name in os.listdir(PACKAGE)
                    if os.path.isfile(os.path.join(PACKAGE, name, '__init__.py')))
    assert layers and all(f'| `{name}/` |' in page for name in layers), layers
    csrc = os.path.join(PACKAGE, 'core', '_csrc')
    folders = sorted(name for name in os.listdir(csrc) if os.path.isdir(os.path.join(csrc, name)))
    assert folders and all(f'| `core/_csrc/{name}/` |' in page for name in folders), folders


def test_every_module_of_a_concept_across_layers_is_named_with_its_role():
    page = _page()
    table = page[page.index('## One concept across layers'):]
    unnamed = []
    for folder, _, names in os.walk(PACKAGE):
        for name in names:
            if name.endswith('.py') and name[:-3] in CONCEPT_STEMS:
                path = os.path.relpath(os.path.join(folder, name), PACKAGE).replace(os.sep, '/')
                if f'`{path}`' not in table:
                    unnamed.append(path)
    assert not unnamed, f'no role on docs/architecture.md for: {unnamed}'


def test_the_where_to_change_table_keeps_its_tasks():
    page = _page()
    table = page[page.index('## Where to change what'):page.index('## One concept')]
    rows = [line for line in table.splitlines() if line.startswith('| ')]
    missing = [task for task in TASKS if not any(task in row for row in rows)]
    assert not missing, f'tasks without a row: {missing}'


def test_the_readme_and_the_development_guide_link_the_page():
    for doc, link in (('README.md', 'docs/architecture.md'),
                      (os.path.join('docs', 'development.md'), 'architecture.md')):
        with open(os.path.join(ROOT, doc), encoding='utf-8') as stream:
            assert f']({link}' in stream.read(), doc
