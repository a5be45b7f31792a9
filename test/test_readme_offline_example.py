"""
The README's offline controller example runs as printed and does what the README says.

The ``python`` block under "A controller that settles" that uses Simulator is taken from
README.md as it is and run; Δy must reach 3 mm within 1 %, and the line it prints must be the
one its last comment shows.
"""

import contextlib
import io
import os
import re

README = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'README.md')
SECTION = '## A controller that settles'
TARGET = 3.0e-3   # m, the example's set point


def offline_example(text: str) -> str:
    """Return the code of the section's python block that uses Simulator (exactly one)."""
    start = text.index(SECTION)
    end = text.find('\n## ', start + len(SECTION))
    section = text[start:end if end >= 0 else len(text)]
    blocks = [b for b in re.findall(r'^```python\n(.*?)^```$', section, re.S | re.M)
              if 'Simulator' in b]
    assert len(blocks) == 1, f'{len(blocks)} python blocks with Simulator under {SECTION!r}'
    return blocks[0]


def test_the_readme_offline_controller_reaches_3_mm_and_prints_its_comment():
    with open(README, encoding='utf-8') as stream:
        code = offline_example(stream.read())
    printed = io.StringIO()
    namespace = {'__name__': '__readme__'}
    with contextlib.redirect_stdout(printed):
        exec(compile(code, 'README.md (A controller that settles)', 'exec'), namespace)
    assert abs(namespace['dy'] - TARGET) <= 0.01 * TARGET, namespace['dy']
    print_line = next(line for line in code.splitlines() if line.startswith('print('))
    shown = print_line.split('# ', 1)[1].strip()
    assert printed.getvalue().strip() == shown
