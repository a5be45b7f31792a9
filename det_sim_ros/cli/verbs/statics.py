"""
``det_sim statics``: equilibrium branches, potential and delta-y against pre-strain.

The equilibrium branches against pre-strain, the potential (eq 82) and delta-y, at 0 V and
v_max (the paper's Fig. 5); CSV files and one PNG per beam. The paper's one-term model
(``fidelity: paper``) unless ``--set scene.fidelity=...`` names another level.
"""

from __future__ import annotations

import math
import os

from .. import common

HELP = 'equilibrium branches vs pre-strain, potential (eq 82), delta-y'
COLORS = {0: 'tab:blue', 1: 'tab:red'}
POT_COLORS = ('tab:green', 'tab:purple', 'tab:orange', 'tab:brown', 'tab:olive', 'tab:cyan')


def add_arguments(parser) -> None:
    """Add the scene options, --beams, --eps-range, --eps-b, --n-q."""
    common.add_scene_arguments(parser)
    parser.add_argument('--beams', type=common.beam_list, default=None,
                        help="comma-separated beams (default: the scene's beam)")
    parser.add_argument('--eps-range', type=common.eps_range, default='0:0.3:61',
                        metavar='START:STOP:N', help='pre-strain grid (default: 0:0.3:61)')
    parser.add_argument('--eps-b', type=common.float_list, default='0.15,0.20,0.25',
                        help='pre-strains for the potential plot (default: 0.15,0.20,0.25)')
    parser.add_argument('--n-q', type=int, default=201, help='points of the potential curves')


def main(args) -> int:
    """Sweep every beam, write the CSV files (and PNGs), print the critical pre-strains."""
    base = common.paper_level(common.base_scene(args), args)
    beams = args.beams or [base.beam]
    out = common.out_dir(args)
    voltages = (0.0, base.physics.v_max)
    if args.n_q < 3:
        raise common.CliError(f'--n-q must be >= 3 (got {args.n_q})')
    sweep = _Sweep(args, voltages)
    bar = common.Progress(sweep.count(len(beams)), 'statics')
    try:
        results = {beam: sweep.beam(base.replace(**{'scene.beam': beam}), bar)
                   for beam in beams}
    finally:
        bar.close()
    files = [
        common.write_csv(os.path.join(out, 'statics_branches.csv'),
                         ['beam', 'voltage_V', 'eps_b', 'branch', 'q_m', 'y_m', 'delta_y_m',
                          'stable', 'stiffness'], sweep.branch_rows),
        common.write_csv(os.path.join(out, 'statics_potential.csv'),
                         ['beam', 'voltage_V', 'eps_b', 'q_m', 'U_pot_J', 'U_pot_norm'],
                         sweep.pot_rows),
        common.write_csv(os.path.join(out, 'statics_critical.csv'),
                         ['beam', 'voltage_V', 'eps_b_min'], sweep.crit_rows),
    ]
    for beam, v, e in sweep.crit_rows:
        print(f'eps_b,min({beam}, {v:g} V) = {e:.4f}')
    plt = common.pyplot(args)
    if plt is not None:
        for beam, res in results.items():
            files.append(_plot(plt, beam, res, voltages, args, out))
    common.print_written(files)
    return 0


class _Sweep:
    """
    The statics of one beam after another.

    It collects the rows of the three CSV files, and per beam the critical pre-strains,
    branches and normalized potentials the plot draws.
    """

    def __init__(self, args, voltages):
        import numpy as np
        self.voltages = voltages
        self.eps_grid = np.asarray(args.eps_range, dtype=float)
        self.eps_b = args.eps_b
        self.n_q = args.n_q
        self.branch_rows, self.pot_rows, self.crit_rows = [], [], []

    def count(self, n_beams: int) -> int:
        """Return the progress items of ``n_beams`` beams."""
        n_v = len(self.voltages)
        return n_beams * (n_v * (len(self.eps_grid) + 1) + len(self.eps_b) * n_v)

    def beam(self, scene, bar) -> dict:
        """Compute the critical pre-strains, branches and potentials of one beam's scene."""
        from ...physics import statics
        beam = scene.beam
        res = {'crit': {}, 'branches': {}, 'pot': {}}
        for v in self.voltages:
            e_min = statics.critical_prestrain(scene, v)
            res['crit'][v] = e_min
            self.crit_rows.append((beam, v, e_min))
            bar.advance()
            pts = statics.branches(scene, self.eps_grid, v, progress=lambda k: bar.advance())
            res['branches'][v] = pts
            self.branch_rows += [(beam, p.voltage, p.eps_b, p.branch, p.q, p.y, p.delta_y,
                                  p.stable, p.stiffness) for p in pts]
        self._potentials(scene, res, bar)
        return res

    def _potentials(self, scene, res, bar) -> None:
        # potential curves over a q range covering the buckled states at 0 V
        import numpy as np
        from ...physics import statics
        q_star = [e.q for eps in self.eps_b
                  for e in statics.equilibria(scene.replace(**{'scene.eps_b': eps}), 0.0)
                  if e.kind == 'buckled+']
        q_span = 1.3 * max(q_star) if q_star else 0.2 * scene.physics.l0
        q = np.linspace(-q_span, q_span, self.n_q)
        for eps in self.eps_b:
            sc = scene.replace(**{'scene.eps_b': eps})
            for v in self.voltages:
                u = statics.potential(sc, q, v)
                lo, hi = u.min(), u.max()
                un = (u - lo) / (hi - lo) if hi > lo else np.zeros_like(u)
                res['pot'][eps, v] = (q, un)
                self.pot_rows += [(scene.beam, v, eps, qi, ui, ni)
                                  for qi, ui, ni in zip(q, u, un)]
                bar.advance()


def _segments(x, y, flags):
    """Split a curve into runs of equal flag (sharing the boundary points)."""
    runs, start = [], 0
    for k in range(1, len(x) + 1):
        if k == len(x) or flags[k] != flags[start]:
            end = min(k + 1, len(x))
            runs.append((x[start:end], y[start:end], flags[start]))
            start = k
    return runs


def _plot(plt, beam, res, voltages, args, out):
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    ax_q, ax_u, ax_dy = axes
    for iv, v in enumerate(voltages):
        _plot_branches(ax_q, ax_dy, res['branches'][v], res['crit'][v], COLORS[iv])
        ax_q.plot([], [], '-', color=COLORS[iv], label=f'{v / 1e3:g} kV')
        ax_dy.plot([], [], '-', color=COLORS[iv], label=f'{v / 1e3:g} kV')
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


def _plot_branches(ax_q, ax_dy, pts, e_min, color) -> None:
    """Draw q and delta-y of each branch at one voltage (dashed where unstable)."""
    import numpy as np
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
