"""
What the verbs of ``det_sim`` share.

Argument types and the scene options, the progress bar, output files, the matplotlib loader,
and one-line errors with their exit codes.

Nothing heavy is imported here at module level: the dispatcher imports every verb to build its
parser, and a verb imports numpy, the model or rclpy only when it runs.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import time

PLOTS_HINT = ('matplotlib is not installed: wrote the CSV files only; for the plots install '
              "the extra: pip install 'det_sim_ros[plots]' (or pip install matplotlib)")
# set to 1 to see the traceback of an unexpected error (the tools print one line otherwise)
TRACEBACK_ENV = 'DET_SIM_TRACEBACK'


class CliError(ValueError):
    """A bad command-line value (reported as one line, exit code 2)."""


class Progress:
    """A plain stderr progress bar that appears only once a sweep has run longer than ``delay``."""

    def __init__(self, total: int, label: str, stream=None, delay: float = 1.0, width: int = 30):
        self.total = max(int(total), 1)
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.delay = delay
        self.width = width
        self.start = time.monotonic()
        self.shown = False
        self.done = 0
        self._drawn = -1.0

    def update(self, done: int) -> None:
        """Show ``done`` of ``total`` (redrawn at most ~10 times a second)."""
        self.done = done
        elapsed = time.monotonic() - self.start
        if not self.shown and elapsed < self.delay:
            return
        if self.shown and done < self.total and elapsed - self._drawn < 0.1:
            return
        self.shown = True
        self._drawn = elapsed
        filled = int(self.width * min(done, self.total) / self.total)
        self.stream.write(f'\r{self.label} [{"#" * filled}{"." * (self.width - filled)}] '
                          f'{done}/{self.total} {elapsed:5.1f} s')
        self.stream.flush()

    def advance(self, n: int = 1) -> None:
        """Count ``n`` more items done."""
        self.update(self.done + n)

    def close(self) -> None:
        """End the bar's line (if it was shown)."""
        if self.shown:
            self.stream.write('\n')
            self.stream.flush()


# -- argument types ---------------------------------------------------------------------------
def parse_set(text: str):
    """Split ``key=value`` into (key, value read as YAML; numbers such as 1e3 as floats)."""
    import yaml
    key, sep, value = text.partition('=')
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f'expected key=value, got {text!r}')
    try:
        parsed = yaml.safe_load(value)
    except yaml.YAMLError:
        parsed = value
    if isinstance(parsed, str):
        try:
            parsed = float(parsed)          # YAML 1.1 reads 1e3 as text: accept it as a number
        except ValueError:
            pass
    return key.strip(), parsed


def float_list(text: str) -> list[float]:
    """Parse comma-separated finite numbers."""
    try:
        values = [float(v) for v in text.split(',') if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated numbers, got {text!r}') \
            from None
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f'expected comma-separated finite numbers, got {text!r}')
    return values


def beam_list(text: str) -> list[str]:
    """Parse comma-separated beam kinds (det_sim_ros.scenes.scene.BEAMS)."""
    from ..scenes.scene import BEAMS
    beams = [b.strip() for b in text.split(',') if b.strip()]
    bad = [b for b in beams if b not in BEAMS]
    if bad or not beams:
        raise argparse.ArgumentTypeError(f'unknown beam {bad[0] if bad else text!r}; choose from '
                                         + ', '.join(BEAMS))
    return beams


def eps_range(text: str):
    """Parse ``START:STOP:N`` into N evenly spaced values (numpy array)."""
    import numpy as np
    parts = text.split(':')
    try:
        if len(parts) != 3:
            raise ValueError
        start, stop, num = float(parts[0]), float(parts[1]), int(parts[2])
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected START:STOP:N (e.g. 0:0.3:61), got {text!r}') \
            from None
    if num < 2 or not stop > start:
        raise argparse.ArgumentTypeError(f'need STOP > START and N >= 2, got {text!r}')
    return np.linspace(start, stop, num)


def positive(text: str) -> float:
    """Parse a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}') from None
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be > 0, got {text!r}')
    return value


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of the verbs that run a scene: --scene, --set, --out, --dpi, --no-plots."""
    parser.add_argument('--scene', default='default',
                        help="scene file path or installed scene name (default: 'default')")
    parser.add_argument('--set', dest='overrides', action='append', type=parse_set, default=[],
                        metavar='KEY=VALUE',
                        help='override a scene parameter, e.g. physics.Rs=1e3 (repeatable)')
    parser.add_argument('--out', default='det_sim_out',
                        help='output folder (default: %(default)s)')
    parser.add_argument('--dpi', type=int, default=80, help='PNG resolution (default: 80)')
    parser.add_argument('--no-plots', action='store_true', help='write the CSV files only')


def base_scene(args):
    """Load the scene of --scene with the --set overrides."""
    from ..scenes.scene import load_scene
    return load_scene(args.scene, overrides=dict(args.overrides))


def user_set(args, *keys) -> bool:
    """Return True if one of ``keys`` was given with --set."""
    return any(k in keys for k, _ in args.overrides)


def paper_level(scene, args):
    """
    Return ``scene`` at the paper's fidelity unless --set names a fidelity.

    The paper's scenarios (``det_sim statics``, ``det_sim step``) compare with the paper, so
    they run its one-term model whatever the scene file's level.
    """
    if user_set(args, 'scene.fidelity', 'fidelity'):
        return scene
    return scene.replace(**{'scene.fidelity': 'paper'})


# -- output files -----------------------------------------------------------------------------
def out_dir(args) -> str:
    """Return the --out folder, created if needed."""
    os.makedirs(args.out, exist_ok=True)
    return args.out


def write_csv(path: str, header, rows) -> str:
    """Write a CSV file (floats with 10 significant digits, booleans as 0/1); return ``path``."""
    with open(path, 'w', newline='', encoding='utf-8') as stream:
        writer = csv.writer(stream)
        writer.writerow(header)
        for row in rows:
            writer.writerow([_cell(v) for v in row])
    return path


def _cell(value):
    import numpy as np
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return f'{value:.10g}'
    return value


def log_runs_to_use(paths, verb: str, each: bool | None = None) -> list[list[str]]:
    """
    Return the runs of sim_node logs to work on, each as its files: every run with ``each``.

    Else the newest one; when ``paths`` (a log directory) hold several runs, one line says
    which run is used, how many others there are and how to pick another. ``each`` None: the
    verb has no option for every run. Files that are not sim_node logs are left out, named in
    one line; when no run is left they are returned, for the verb's checks to say what is
    wrong with them.
    """
    from ..io.log import log_files, log_runs
    try:
        runs = log_runs(paths)
    except FileNotFoundError as exc:
        raise CliError(str(exc)) from None
    if not runs:
        return [log_files(paths)]
    if runs.unreadable:
        print(f'det_sim {verb}: {runs.unreadable_line()}', flush=True)
    if each or len(runs) == 1:
        return [list(run.files) for run in runs]
    newest, other = runs[-1], runs[-2]
    example = other.files[0] + (f' {os.path.dirname(other.files[0]) or os.curdir}'
                                f'{os.sep}{other.name}_*.mcap' if len(other.files) > 1 else '')
    print(f'det_sim {verb}: the newest of {len(runs)} runs, {newest.name} '
          f'({len(newest.files)} file(s)); for another pass its files (e.g. {example})'
          + (' or --each-run for every run' if each is not None else ''), flush=True)
    return [list(newest.files)]


def write_text(path: str, text: str) -> str:
    """Write a UTF-8 text file; return ``path``."""
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write(text)
    return path


def print_written(paths) -> None:
    """Print ``wrote PATH`` for each file written, on stdout."""
    for path in paths:
        print(f'wrote {path}')


def pyplot(args, prog: str = 'det_sim'):
    """Return matplotlib.pyplot with the Agg backend, or None (with a hint) if unavailable/off."""
    if args.no_plots:
        return None
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print(f'{prog}: {PLOTS_HINT}', file=sys.stderr)
        return None
    return plt


def missing_modules(names) -> list[str]:
    """Return those of the modules ``names`` that cannot be imported."""
    import importlib
    missing = []
    for name in names:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    return missing


# -- one-line errors ----------------------------------------------------------------------------
def _input_errors() -> tuple:
    """Return the errors that mean bad input (exit code 2), imported once an error is raised."""
    from ..calibration.measurement import CalibrationError
    from ..io.logplot import LogPlotError
    from ..physics.linearize import LinearizationError
    from ..ros.fleet import FleetError
    from ..scenes.scene import SceneError
    return SceneError, CliError, LinearizationError, LogPlotError, FleetError, CalibrationError


def _domain_error() -> type:
    from ..physics.model import ModelDomainError
    return ModelDomainError


def interruptible() -> None:
    """Let SIGINT raise KeyboardInterrupt again and SIGTERM end the process (main thread)."""
    import signal
    import threading
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def run(action, args, prog: str) -> int:
    """
    Run ``action(args)`` as a command and return its exit code.

    The exit code is the action's own, or, after one line on stderr, the error's code (2 bad
    input, 1 the model's domain left, a file error or any other failure, 130 Ctrl-C).
    """
    try:
        return int(action(args) or 0)
    except KeyboardInterrupt:
        print(f'{prog}: interrupted', file=sys.stderr)
        return 130
    except _input_errors() as exc:
        print(f'{prog}: error: {_one_line(exc)}', file=sys.stderr)
        return 2
    except _domain_error() as exc:
        print(f'{prog}: error: the simulation left the model domain: {_one_line(exc)}',
              file=sys.stderr)
        return 1
    except (OSError, ValueError) as exc:
        print(f'{prog}: error: {_one_line(exc)}', file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - a command line tool answers in one line
        if os.environ.get(TRACEBACK_ENV) == '1':
            raise
        print(f'{prog}: error: {type(exc).__name__}: {_one_line(exc)} (set {TRACEBACK_ENV}=1 '
              'for the traceback)', file=sys.stderr)
        return 1


def _one_line(exc) -> str:
    """Return an error's message on one line (a YAML parser's spans several, with a caret)."""
    return ' '.join(str(exc).split())
