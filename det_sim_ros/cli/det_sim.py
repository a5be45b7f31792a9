"""
``det_sim``: run the DET-buckled-beam model offline (no ROS) and write data (CSV) and plots (PNG).

Subcommands::

    det_sim statics [--beams fixed,simply_supported] [--eps-range 0:0.3:61]
                    [--eps-b 0.15,0.20,0.25]
    det_sim step    [--beams fixed,simply_supported] [--eps-b 0.15,0.20,0.25] [--t-end 4.5]
    det_sim bench   [...]            (the integration benchmark, det_sim_ros.analysis.benchmark)
    det_sim plot LOG.mcap [--out DIR]                 (every channel of a sim_node log, PNG)
    det_sim linearize [--voltage 1500] [--branch buckled+] [--json]   (A, B, C, D; Bode)
    det_sim fleet FLEET.yaml [--host NAME] [--log-dir DIR]   (sim_node processes, one per
                    namespace; Ctrl-C stops them all; det_sim_ros.ros.fleet describes the file)

Common options: ``--scene PATH_OR_NAME`` (default 'default'), ``--set key=value`` (repeatable,
e.g. ``--set physics.Rs=1e3 --set scene.fidelity=consistent``), ``--out DIR`` (default
./det_sim_out), ``--dpi N`` (``plot`` takes only ``--out`` and ``--dpi``). Plots need matplotlib
(``pip install .[plots]``); without it the CSV files are still written. Bad arguments and invalid scenes give one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import time

import numpy as np
import yaml

from ..physics import statics
from ..ros.fleet import FleetError
from ..physics.linearize import LinearizationError
from ..io.logplot import LogPlotError
from ..physics.model import ModelDomainError
from ..scenes.scene import BEAMS, load_scene, SceneError

__all__ = ['main', 'Progress', 'PAPER_SWITCHED', 'PAPER_EPS_Y']

PROG = 'det_sim'
# What the paper reports for the 'step' scenario (Section 4, Fig. 6)
PAPER_SWITCHED = {0.15: True, 0.20: True, 0.25: False}
PAPER_EPS_Y = {'simply_supported': 0.065, 'fixed': 0.08}
PLOTS_HINT = ("matplotlib is not installed: wrote the CSV files only; for the plots install "
              "the extra: pip install 'det_sim_ros[plots]' (or pip install matplotlib)")
COLORS = {0: 'tab:blue', 1: 'tab:red'}
POT_COLORS = ('tab:green', 'tab:purple', 'tab:orange', 'tab:brown', 'tab:olive', 'tab:cyan')


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
        self.done = done
        elapsed = time.monotonic() - self.start
        if not self.shown and elapsed < self.delay:
            return
        if self.shown and done < self.total and elapsed - self._drawn < 0.1:
            return                                    # redraw at most ~10 times a second
        self.shown = True
        self._drawn = elapsed
        filled = int(self.width * min(done, self.total) / self.total)
        self.stream.write(f'\r{self.label} [{"#" * filled}{"." * (self.width - filled)}] '
                          f'{done}/{self.total} {elapsed:5.1f} s')
        self.stream.flush()

    def advance(self, n: int = 1) -> None:
        self.update(self.done + n)

    def close(self) -> None:
        if self.shown:
            self.stream.write('\n')
            self.stream.flush()


# -- argument parsing -----------------------------------------------------------------------------
def _parse_set(text: str):
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


def _float_list(text: str):
    try:
        values = [float(v) for v in text.split(',') if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated numbers, got {text!r}') \
            from None
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f'expected comma-separated finite numbers, got {text!r}')
    return values


def _beam_list(text: str):
    beams = [b.strip() for b in text.split(',') if b.strip()]
    bad = [b for b in beams if b not in BEAMS]
    if bad or not beams:
        raise argparse.ArgumentTypeError(f'unknown beam {bad[0] if bad else text!r}; choose from '
                                         + ', '.join(BEAMS))
    return beams


def _eps_range(text: str):
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


def _positive(text: str):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}') from None
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be > 0, got {text!r}')
    return value


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument('--scene', default='default',
                        help="scene file path or installed scene name (default: 'default')")
    common.add_argument('--set', dest='overrides', action='append', type=_parse_set, default=[],
                        metavar='KEY=VALUE',
                        help='override a scene parameter, e.g. physics.Rs=1e3 (repeatable)')
    common.add_argument('--out', default='det_sim_out',
                        help='output folder (default: %(default)s)')
    common.add_argument('--dpi', type=int, default=80, help='PNG resolution (default: 80)')
    common.add_argument('--no-plots', action='store_true', help='write the CSV files only')

    parser = argparse.ArgumentParser(
        prog=PROG, description='Run the DET-buckled-beam model offline (no ROS): statics '
        '(Fig. 5), step responses (Fig. 6), integration benchmark, plots of sim_node logs, '
        'linear models. Writes CSV, JSON and PNG files. And with ROS: fleet starts several '
        'sim_node processes from one YAML file.')
    sub = parser.add_subparsers(dest='command',
                                metavar='{statics,step,bench,plot,linearize,fleet}')

    p = sub.add_parser('statics', parents=[common],
                       help='equilibrium branches vs pre-strain, potential (eq 82), delta-y')
    p.add_argument('--beams', type=_beam_list, default=None,
                   help="comma-separated beams (default: the scene's beam)")
    p.add_argument('--eps-range', type=_eps_range, default=_eps_range('0:0.3:61'),
                   metavar='START:STOP:N', help='pre-strain grid (default: 0:0.3:61)')
    p.add_argument('--eps-b', type=_float_list, default=[0.15, 0.20, 0.25],
                   help='pre-strains for the potential plot (default: 0.15,0.20,0.25)')
    p.add_argument('--n-q', type=int, default=201, help='points of the potential curves')
    p.set_defaults(func=cmd_statics)

    p = sub.add_parser('step', parents=[common],
                       help="the 'step' scenario (0 V, v_max at 1.5 s, 0 V at 3 s)")
    p.add_argument('--beams', type=_beam_list, default=['fixed', 'simply_supported'],
                   help='comma-separated beams (default: fixed,simply_supported)')
    p.add_argument('--eps-b', type=_float_list, default=[0.15, 0.20, 0.25],
                   help='pre-strains (default: 0.15,0.20,0.25)')
    p.add_argument('--t-end', type=_positive, default=4.5, help='end time, s (default: 4.5)')
    p.set_defaults(func=cmd_step)

    p = sub.add_parser('plot', help='PNG of every channel of a sim_node MCAP log against sim '
                       'time, and a text summary')
    p.add_argument('log', nargs='+', help='MCAP file(s) or a directory of split files')
    p.add_argument('--out', default=None,
                   help='output folder (default: the folder of the log)')
    p.add_argument('--dpi', type=int, default=80, help='PNG resolution (default: 80)')
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser('linearize', parents=[common],
                       help='linear model (A, B, C, D) at an equilibrium: poles, damping, '
                       'natural frequencies, DC gains, Bode plot')
    p.add_argument('--voltage', type=_float_list, default=[0.0],
                   help='DET voltage(s), V: one for all DETs or one per DET (default: 0)')
    p.add_argument('--branch', default='buckled+',
                   help='equilibrium branch: buckled+ (default), buckled- or straight')
    p.add_argument('--json', action='store_true', help='print the result as JSON')
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser('fleet', help='start the sim_nodes of a fleet file on this host (one '
                       'process per namespace, logs per node); SIGINT/SIGTERM stop them all',
                       description='Start the sim_node processes a fleet YAML file lists for '
                       'this host, each in its namespace with its log file; forward SIGINT and '
                       'SIGTERM to all; exit 0 once every node stopped cleanly. Across hosts, '
                       'run the same file on every host (nodes with host: start on that host '
                       'only). File format: README, section Fleets.')
    p.add_argument('file', help='fleet YAML file')
    p.add_argument('--host', default=None,
                   help="start the nodes for this host name (default: this machine's)")
    p.add_argument('--log-dir', default=None,
                   help="node logs folder (default: the file's log_dir, else fleet_logs)")
    p.add_argument('--stop-timeout', type=_positive, default=20.0,
                   help='s to wait for the nodes to stop before killing them (default: 20)')
    p.set_defaults(func=cmd_fleet)

    p = sub.add_parser('bench', add_help=False,
                       help='work-precision diagram of the integration benchmark')
    p.add_argument('bench_args', nargs=argparse.REMAINDER)
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``det_sim`` console script; returns the exit code."""
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ['bench']:          # everything after 'bench' belongs to the benchmark
        return _run_bench(argv[1:])
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:        # argparse: --help (0) or a bad argument (2)
        return int(exc.code or 0)
    if args.command is None:
        parser.print_usage(sys.stderr)
        print(f'{PROG}: error: choose a subcommand: statics, step, bench, plot, linearize or '
              'fleet',
              file=sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except (SceneError, CliError, LinearizationError, LogPlotError, FleetError) as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2
    except ModelDomainError as exc:
        print(f'{PROG}: error: the simulation left the model domain: {exc}', file=sys.stderr)
        return 1
    except OSError as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted', file=sys.stderr)
        return 130


# -- helpers ------------------------------------------------------------------------------------
def _base_scene(args):
    return load_scene(args.scene, overrides=dict(args.overrides))


def _user_set(args, *keys):
    return any(k in keys for k, _ in args.overrides)


def _out_dir(args):
    os.makedirs(args.out, exist_ok=True)
    return args.out


def _write_csv(path, header, rows):
    with open(path, 'w', newline='', encoding='utf-8') as stream:
        writer = csv.writer(stream)
        writer.writerow(header)
        for row in rows:
            writer.writerow([_fmt(v) for v in row])
    return path


def _fmt(value):
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return f'{value:.10g}'
    return value


def _pyplot(args):
    """matplotlib.pyplot with the Agg backend, or None (with a hint) if unavailable/disabled."""
    if args.no_plots:
        return None
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print(f'{PROG}: {PLOTS_HINT}', file=sys.stderr)
        return None
    return plt


def _segments(x, y, flags):
    """Split a curve into runs of equal flag (sharing the boundary points)."""
    runs, start = [], 0
    for k in range(1, len(x) + 1):
        if k == len(x) or flags[k] != flags[start]:
            end = min(k + 1, len(x))
            runs.append((x[start:end], y[start:end], flags[start]))
            start = k
    return runs


# -- statics --------------------------------------------------------------------------------------
def cmd_statics(args) -> int:
    base = _base_scene(args)
    beams = args.beams or [base.beam]
    out = _out_dir(args)
    v_max = base.physics.v_max
    voltages = (0.0, v_max)
    eps_grid = np.asarray(args.eps_range, dtype=float)
    n_q = args.n_q
    if n_q < 3:
        raise CliError(f'--n-q must be >= 3 (got {n_q})')
    branch_rows, pot_rows, crit_rows = [], [], []
    results = {}
    bar = Progress(len(beams) * (len(voltages) * (len(eps_grid) + 1)
                                 + len(args.eps_b) * len(voltages)), 'statics')
    try:
        for beam in beams:
            scene = base.replace(**{'scene.beam': beam})
            res = {'crit': {}, 'branches': {}, 'pot': {}}
            for v in voltages:
                e_min = statics.critical_prestrain(scene, v)
                res['crit'][v] = e_min
                crit_rows.append((beam, v, e_min))
                bar.advance()
                pts = statics.branches(scene, eps_grid, v, progress=lambda k: bar.advance())
                res['branches'][v] = pts
                branch_rows += [(beam, p.voltage, p.eps_b, p.branch, p.q, p.y, p.delta_y,
                                 p.stable, p.stiffness) for p in pts]
            # potential curves over a q range covering the buckled states at 0 V
            q_star = [e.q for eps in args.eps_b
                      for e in statics.equilibria(scene.replace(**{'scene.eps_b': eps}), 0.0)
                      if e.kind == 'buckled+']
            q_span = 1.3 * max(q_star) if q_star else 0.2 * scene.physics.l0
            q = np.linspace(-q_span, q_span, n_q)
            for eps in args.eps_b:
                sc = scene.replace(**{'scene.eps_b': eps})
                for v in voltages:
                    u = statics.potential(sc, q, v)
                    lo, hi = u.min(), u.max()
                    un = (u - lo) / (hi - lo) if hi > lo else np.zeros_like(u)
                    res['pot'][eps, v] = (q, un)
                    pot_rows += [(beam, v, eps, qi, ui, ni) for qi, ui, ni in zip(q, u, un)]
                    bar.advance()
            results[beam] = res
    finally:
        bar.close()
    files = [
        _write_csv(os.path.join(out, 'statics_branches.csv'),
                   ['beam', 'voltage_V', 'eps_b', 'branch', 'q_m', 'y_m', 'delta_y_m', 'stable',
                    'stiffness'], branch_rows),
        _write_csv(os.path.join(out, 'statics_potential.csv'),
                   ['beam', 'voltage_V', 'eps_b', 'q_m', 'U_pot_J', 'U_pot_norm'], pot_rows),
        _write_csv(os.path.join(out, 'statics_critical.csv'),
                   ['beam', 'voltage_V', 'eps_b_min'], crit_rows),
    ]
    for beam, v, e in crit_rows:
        print(f'eps_b,min({beam}, {v:g} V) = {e:.4f}')
    plt = _pyplot(args)
    if plt is not None:
        for beam, res in results.items():
            files.append(_plot_statics(plt, beam, res, voltages, args, out))
    for path in files:
        print(f'wrote {path}')
    return 0


def _plot_statics(plt, beam, res, voltages, args, out):
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    ax_q, ax_u, ax_dy = axes
    for iv, v in enumerate(voltages):
        color = COLORS[iv]
        e_min = res['crit'][v]
        pts = res['branches'][v]
        for name in sorted({p.branch for p in pts}):
            sel = [p for p in pts if p.branch == name]
            eps = [p.eps_b for p in sel]
            q = [p.q * 1e3 for p in sel]
            dy = [p.delta_y * 1e3 for p in sel]
            st = [p.stable for p in sel]
            if name != 'straight' and math.isfinite(e_min) and eps and eps[0] > e_min:
                eps, q, st = [e_min] + eps, [0.0] + q, [st[0]] + st   # join the bifurcation A
                dy = [dy[0] if name == 'straight' else np.nan] + dy
            for xs, ys, stable in _segments(eps, q, st):
                ax_q.plot(xs, ys, '-' if stable else '--', color=color, lw=1.5)
            if name.startswith('buckled-'):
                continue                             # delta-y of the mirror branch is the same
            for xs, ys, stable in _segments(eps, dy, st):
                ax_dy.plot(xs, ys, '-' if stable else '--', color=color, lw=1.5)
        if math.isfinite(e_min):
            ax_q.plot([e_min], [0.0], 'o', color=color, ms=4)
        ax_q.plot([], [], '-', color=color, label=f'{v / 1e3:g} kV')
        ax_dy.plot([], [], '-', color=color, label=f'{v / 1e3:g} kV')
    ax_q.plot([], [], 'k--', lw=1, label='unstable')
    ax_q.set(xlabel=r'pre-strain $\varepsilon_b$', ylabel='q (mm)', title='equilibria (a)')
    ax_q.legend(fontsize=8)
    styles = {voltages[0]: '-', voltages[1]: ':'}
    for k, eps in enumerate(args.eps_b):
        for v in voltages:
            q, un = res['pot'][eps, v]
            ax_u.plot(q * 1e3, un, styles[v], color=POT_COLORS[k % len(POT_COLORS)],
                      label=rf'$\varepsilon_b$={eps:g}, {v / 1e3:g} kV')
    ax_u.set(xlabel='q (mm)', ylabel=r'$U_{pot,n}$', title='normalized potential, eq 82 (c)')
    ax_u.legend(fontsize=7)
    ax_dy.set(xlabel=r'pre-strain $\varepsilon_b$', ylabel=r'$\Delta y = y_0 - y$ (mm)',
              title=r'$\Delta y$ of the branches (e)')
    ax_dy.legend(fontsize=8)
    fig.suptitle(f'statics, {beam.replace("_", " ")} beam')
    fig.tight_layout()
    path = os.path.join(out, f'statics_{beam}.png')
    fig.savefig(path, dpi=args.dpi)
    plt.close(fig)
    return path


# -- step -----------------------------------------------------------------------------------------
def _step_metrics(t, q, y, l_beam, scene):
    """y0, delta_y, eps_y and the comparison numbers of one 'step' run."""
    from ..analysis.scenarios import STEP_SWITCH_TIMES
    t_on, t_off = STEP_SWITCH_TIMES
    if t[-1] >= t_on:
        i_on = int(np.searchsorted(t, t_on - 1e-9))
        y0 = y[i_on]
    else:                                  # no 3 kV phase simulated: y0 from the statics
        i_on = None
        y0 = statics.rest_shortening(scene)
    dy = y0 - y
    eps_y = dy / (l_beam - y0)
    info = {'switched': None, 'eps_y_on': math.nan, 'q_before': math.nan, 'q_on_end': math.nan,
            'q_final': float(q[-1])}
    if i_on is not None and t[-1] > t_on:
        i_end = int(np.searchsorted(t, t_off - 1e-9)) - 1   # last sample before switch-off
        i_end = min(max(i_end, i_on + 1), len(t) - 1)
        info.update(switched=bool(np.sign(q[i_end]) != np.sign(q[i_on])),
                    eps_y_on=float(eps_y[i_end]), q_before=float(q[i_on]),
                    q_on_end=float(q[i_end]))
    return dy, eps_y, info


def _yes_no(flag):
    return '-' if flag is None else ('yes' if flag else 'no')


def cmd_step(args) -> int:
    from ..analysis.scenarios import step_voltage
    from ..sim.simulator import simulate
    base = _base_scene(args)
    out = _out_dir(args)
    if not _user_set(args, 'rate_hz'):
        base = base.replace(rate_hz=1000.0)          # scenarios.md: 1 ms samples
    if not _user_set(args, 'scene.initial_state', 'initial_state'):
        # scenarios.md: released from q0 (the 0 V phase is the beam buckling into rest)
        base = base.replace(**{'scene.initial_state': 'released'})
    runs = {}
    rows = []
    bar = Progress(len(args.beams) * len(args.eps_b), 'step')
    try:
        for beam in args.beams:
            for eps in args.eps_b:
                scene = base.replace(**{'scene.beam': beam, 'scene.eps_b': eps})
                r = simulate(scene, step_voltage(scene.physics.v_max), args.t_end)
                q, y = r['q'], r['y']
                dy, eps_y, info = _step_metrics(r.t, q, y, scene.beam_length, scene)
                runs[beam, eps] = (r.t, q, dy, eps_y, info)
                v = r.u[:, 0]
                rows += [(beam, eps, *vals) for vals in zip(r.t, v, q, y, dy, eps_y)]
                bar.advance()
    finally:
        bar.close()
    files = [_write_csv(os.path.join(out, 'step.csv'),
                        ['beam', 'eps_b', 't_s', 'v_V', 'q_m', 'y_m', 'delta_y_m', 'eps_y'], rows)]
    comp = []
    for (beam, eps), (_, _, _, _, info) in runs.items():
        paper_sw = PAPER_SWITCHED.get(round(eps, 4))
        comp.append((beam, eps, _yes_no(info['switched']), _yes_no(paper_sw),
                     100 * info['eps_y_on'], 100 * PAPER_EPS_Y[beam], info['q_before'],
                     info['q_on_end'], info['q_final']))
    files.append(_write_csv(os.path.join(out, 'paper_comparison.csv'),
                            ['beam', 'eps_b', 'switched', 'switched_paper', 'eps_y_percent',
                             'eps_y_paper_percent', 'q_before_m', 'q_end_of_vmax_m',
                             'q_final_m'], comp))
    md = _comparison_markdown(comp)
    md_path = os.path.join(out, 'paper_comparison.md')
    with open(md_path, 'w', encoding='utf-8') as stream:
        stream.write(md)
    files.append(md_path)
    print(md, end='')
    plt = _pyplot(args)
    if plt is not None:
        files.append(_plot_step(plt, runs, args, out))
    for path in files:
        print(f'wrote {path}')
    return 0


def _comparison_markdown(comp):
    lines = ['| beam | eps_b | switched (ours) | switched (paper) | eps_y at end of v_max '
             '(ours) | eps_y (paper) |',
             '|---|---|---|---|---|---|']
    for beam, eps, sw, sw_p, ey, ey_p, *_ in comp:
        ey_txt = '-' if not math.isfinite(ey) else f'{ey:.1f} %'
        lines.append(f'| {beam.replace("_", " ")} | {eps:.2f} | {sw} | {sw_p} | {ey_txt} | '
                     f'~{ey_p:g} % |')
    return '\n'.join(lines) + '\n'


def _plot_step(plt, runs, args, out):
    beams = list(args.beams)
    fig, axes = plt.subplots(3, len(beams), figsize=(5.5 * len(beams), 7.5), sharex=True,
                             squeeze=False)
    for col, beam in enumerate(beams):
        for k, eps in enumerate(args.eps_b):
            t, q, dy, eps_y, _ = runs[beam, eps]
            kw = dict(color=f'C{k}', lw=1.0, label=rf'$\varepsilon_b$ = {eps:g}',
                      zorder=len(args.eps_b) - k + 1)       # smaller pre-strains on top
            axes[0, col].plot(t, q * 1e3, **kw)
            axes[1, col].plot(t, dy * 1e3, **kw)
            axes[2, col].plot(t, eps_y * 100, **kw)
        axes[0, col].set_title(f'{beam.replace("_", " ")} beam')
        axes[0, col].set_ylabel('q (mm)')
        axes[1, col].set_ylabel(r'$\Delta y$ (mm)')
        axes[2, col].set_ylabel(r'$\varepsilon_y$ (%)')
        axes[2, col].set_xlabel('t (s)')
        for ax in axes[:, col]:
            ax.axvspan(1.5, min(3.0, t[-1]), color='0.9', zorder=0)
            ax.grid(alpha=0.3)
        axes[0, col].legend(fontsize=8, loc='upper right')
    fig.suptitle("step scenario: 0 V, v_max from 1.5 s to 3 s (shaded), 0 V")
    fig.tight_layout()
    path = os.path.join(out, 'step.png')
    fig.savefig(path, dpi=args.dpi)
    plt.close(fig)
    return path


# -- plot -----------------------------------------------------------------------------------------
def cmd_plot(args) -> int:
    from ..io import logplot
    data = logplot.read_log(args.log)
    first = data.files[0]
    out = args.out or os.path.dirname(os.path.abspath(first))
    os.makedirs(out, exist_ok=True)
    stem = os.path.splitext(os.path.basename(first))[0]
    text = logplot.summary(data)
    print(text, end='')
    summary_path = os.path.join(out, f'{stem}_summary.txt')
    with open(summary_path, 'w', encoding='utf-8') as stream:
        stream.write(text)
    files = [summary_path]
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print(f'{PROG}: {PLOTS_HINT}', file=sys.stderr)
    else:
        files.append(logplot.plot_log(data, os.path.join(out, f'{stem}.png'), dpi=args.dpi))
    for path in files:
        print(f'wrote {path}')
    return 0


# -- linearize ------------------------------------------------------------------------------------
def cmd_linearize(args) -> int:
    import json
    from ..physics.linearize import linearize
    scene = _base_scene(args)
    voltage = args.voltage[0] if len(args.voltage) == 1 else args.voltage
    lin = linearize(scene, voltage, args.branch)
    poles = lin.poles()
    wn, zeta = lin.natural_frequency(poles), lin.damping(poles)
    gain = lin.dc_gain()
    n_in = len(lin.input_names)
    out = _out_dir(args)
    report = {
        'scene': args.scene, 'branch': lin.branch, 'voltage_V': lin.u0.tolist(),
        'inputs': list(lin.input_names), 'outputs': list(lin.output_names),
        'states': list(lin.state_names),
        'equilibrium': {'x': lin.x0.tolist(), 'outputs_m': lin.z0.tolist()},
        'poles': [{'real': float(p.real), 'imag': float(p.imag), 'natural_frequency_rad_s':
                   float(w), 'natural_frequency_Hz': float(w / (2 * math.pi)),
                   'damping_ratio': float(z)} for p, w, z in zip(poles, wn, zeta)],
        'dc_gain_m_per_V': {o: {i: float(gain[r, c]) for c, i in enumerate(lin.input_names)}
                            for r, o in enumerate(lin.output_names)},
        'A': lin.A.tolist(), 'B': lin.B.tolist(), 'C': lin.C.tolist(), 'D': lin.D.tolist(),
    }
    files = []
    json_path = os.path.join(out, 'linearization.json')
    with open(json_path, 'w', encoding='utf-8') as stream:
        json.dump(report, stream, indent=1)
    files.append(json_path)
    plt = _pyplot(args)
    if plt is not None:
        files.append(_plot_bode(plt, lin, poles, args, out))
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    print(f"{args.scene}: {lin.branch} equilibrium at {', '.join(f'{v:g}' for v in lin.u0)} V: "
          + ', '.join(f'{o} = {z * 1e3:.6g} mm' for o, z in zip(lin.output_names, lin.z0)))
    print(f"{'pole (1/s)':>34}  {'f_n (Hz)':>10}  {'zeta':>8}")
    for p, w, z in zip(poles, wn, zeta):
        text = f'{p.real:.6g}' + (f' {"+" if p.imag >= 0 else "-"} {abs(p.imag):.6g}j'
                                  if p.imag else '')
        print(f'{text:>34}  {w / (2 * math.pi):>10.4g}  {z:>8.4f}')
    print('DC gains (m/V):')
    for r, o in enumerate(lin.output_names):
        print(f'  {o:<16}' + '  '.join(f'{gain[r, c]:>12.5g}' for c in range(n_in))
              + (f'   per V of [{", ".join(lin.input_names)}]' if n_in > 1 else ' per V'))
    for path in files:
        print(f'wrote {path}')
    return 0


def _plot_bode(plt, lin, poles, args, out):
    """|G| and phase of dy_i/V_i and q_i/V_i (each DET's own input; at most 6 DETs)."""
    rates = np.abs(poles[np.abs(poles) > 0])
    lo = max(rates.min() / 10.0 if rates.size else 0.1, 1e-2)
    hi = rates.max() * 10.0 if rates.size else 1e4
    omega = np.logspace(np.log10(lo), np.log10(hi), 600)
    G = lin.frequency_response(omega)
    n = len(lin.input_names)
    fig, (ax_m, ax_p) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    f = omega / (2 * math.pi)
    for i in range(min(n, 6)):
        for r, style in ((i, '-'), (n + i, '--')):
            g = G[:, r, i]
            if not np.any(np.abs(g) > 0):       # e.g. a DET at 0 V: force ~ V^2, no gain
                continue
            label = f'{lin.output_names[r]} / V[{lin.input_names[i]}]'
            ax_m.loglog(f, np.abs(g), style, lw=1.2, label=label)
            ax_p.semilogx(f, np.degrees(np.unwrap(np.angle(g))), style, lw=1.2)
    ax_m.set_ylabel('|G| (m/V)')
    ax_p.set_ylabel('phase (deg)')
    ax_p.set_xlabel('frequency (Hz)')
    for ax in (ax_m, ax_p):
        ax.grid(alpha=0.3, which='both')
    ax_m.legend(fontsize=8)
    ax_m.set_title(f'{args.scene}: linearized at {", ".join(f"{v:g}" for v in lin.u0)} V, '
                   f'{lin.branch}')
    fig.tight_layout()
    path = os.path.join(out, 'bode.png')
    fig.savefig(path, dpi=args.dpi)
    plt.close(fig)
    return path


# -- fleet ----------------------------------------------------------------------------------------
def cmd_fleet(args) -> int:
    from ..ros.fleet import run_fleet
    return run_fleet(args.file, host=args.host, log_dir=args.log_dir,
                     stop_timeout=args.stop_timeout)


# -- bench ----------------------------------------------------------------------------------------
def cmd_bench(args) -> int:
    return _run_bench(list(args.bench_args))


def _run_bench(argv) -> int:
    import importlib
    try:
        benchmark = importlib.import_module('det_sim_ros.analysis.benchmark')
    except ModuleNotFoundError as exc:
        if exc.name not in ('det_sim_ros.analysis.benchmark',):
            raise
        print(f'{PROG}: bench is not available (det_sim_ros.analysis.benchmark is not installed)',
              file=sys.stderr)
        return 1
    return int(benchmark.main(list(argv)) or 0)


if __name__ == '__main__':
    sys.exit(main())
