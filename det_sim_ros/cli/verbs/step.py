"""
``det_sim step``: the paper's 'step' scenario per beam and pre-strain.

The scenario is 0 V, v_max from 1.5 s to 3 s, 0 V (Fig. 6); the verb writes the time series,
a comparison with the paper, and a PNG. It runs the paper's one-term model (``fidelity:
paper``) unless ``--set scene.fidelity=...`` names another level.
"""

from __future__ import annotations

import math
import os

from .. import common

HELP = "the 'step' scenario (0 V, v_max at 1.5 s, 0 V at 3 s)"
# What the paper reports for the 'step' scenario (Section 4, Fig. 6)
PAPER_SWITCHED = {0.15: True, 0.20: True, 0.25: False}
PAPER_EPS_Y = {'simply_supported': 0.065, 'fixed': 0.08}


def add_arguments(parser) -> None:
    """Add the scene options, --beams, --eps-b, --t-end."""
    common.add_scene_arguments(parser)
    parser.add_argument('--beams', type=common.beam_list, default='fixed,simply_supported',
                        help='comma-separated beams (default: fixed,simply_supported)')
    parser.add_argument('--eps-b', type=common.float_list, default='0.15,0.20,0.25',
                        help='pre-strains (default: 0.15,0.20,0.25)')
    parser.add_argument('--t-end', type=common.positive, default=4.5,
                        help='end time, s (default: 4.5)')


def main(args) -> int:
    """Run every beam and pre-strain, write step.csv and the paper comparison (and the PNG)."""
    base = common.paper_level(common.base_scene(args), args)
    out = common.out_dir(args)
    if not common.user_set(args, 'rate_hz'):
        base = base.replace(rate_hz=1000.0)          # scenarios.md: 1 ms samples
    if not common.user_set(args, 'scene.initial_state', 'initial_state'):
        # scenarios.md: released from q0 (the 0 V phase is the beam buckling into rest)
        base = base.replace(**{'scene.initial_state': 'released'})
    runs, rows = _run_all(base, args)
    files = [common.write_csv(os.path.join(out, 'step.csv'),
                              ['beam', 'eps_b', 't_s', 'v_V', 'q_m', 'y_m', 'delta_y_m',
                               'eps_y'], rows)]
    comp = []
    for (beam, eps), (_, _, _, _, info) in runs.items():
        paper_sw = PAPER_SWITCHED.get(round(eps, 4))
        comp.append((beam, eps, _yes_no(info['switched']), _yes_no(paper_sw),
                     100 * info['eps_y_on'], 100 * PAPER_EPS_Y[beam], info['q_before'],
                     info['q_on_end'], info['q_final']))
    files.append(common.write_csv(os.path.join(out, 'paper_comparison.csv'),
                                  ['beam', 'eps_b', 'switched', 'switched_paper',
                                   'eps_y_percent', 'eps_y_paper_percent', 'q_before_m',
                                   'q_end_of_vmax_m', 'q_final_m'], comp))
    md = _comparison_markdown(comp)
    files.append(common.write_text(os.path.join(out, 'paper_comparison.md'), md))
    print(md, end='')
    plt = common.pyplot(args)
    if plt is not None:
        files.append(_plot(plt, runs, args, out))
    common.print_written(files)
    return 0


def _run_all(base, args):
    """
    Simulate each beam and pre-strain.

    Return {(beam, eps_b): (t, q, dy, eps_y, info)} and the rows of step.csv.
    """
    from ...analysis.scenarios import step_voltage
    from ...sim.simulator import simulate
    runs, rows = {}, []
    bar = common.Progress(len(args.beams) * len(args.eps_b), 'step')
    try:
        for beam in args.beams:
            for eps in args.eps_b:
                scene = base.replace(**{'scene.beam': beam, 'scene.eps_b': eps})
                r = simulate(scene, step_voltage(scene.physics.v_max), args.t_end)
                q, y = r['q'], r['y']
                dy, eps_y, info = _metrics(r.t, q, y, scene.beam_length, scene)
                runs[beam, eps] = (r.t, q, dy, eps_y, info)
                v = r.u[:, 0]
                rows += [(beam, eps, *vals) for vals in zip(r.t, v, q, y, dy, eps_y)]
                bar.advance()
    finally:
        bar.close()
    return runs, rows


def _metrics(t, q, y, l_beam, scene):
    """Return y0, delta_y, eps_y and the comparison numbers of one 'step' run."""
    import numpy as np
    from ...analysis.scenarios import STEP_SWITCH_TIMES
    from ...physics import statics
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


def _comparison_markdown(comp):
    lines = ['| beam | eps_b | switched (ours) | switched (paper) | eps_y at end of v_max '
             '(ours) | eps_y (paper) |',
             '|---|---|---|---|---|---|']
    for beam, eps, sw, sw_p, ey, ey_p, *_ in comp:
        ey_txt = '-' if not math.isfinite(ey) else f'{ey:.1f} %'
        lines.append(f'| {beam.replace("_", " ")} | {eps:.2f} | {sw} | {sw_p} | {ey_txt} | '
                     f'~{ey_p:g} % |')
    return '\n'.join(lines) + '\n'


def _plot(plt, runs, args, out):
    beams = list(args.beams)
    fig, axes = plt.subplots(3, len(beams), figsize=(5.5 * len(beams), 7.5), sharex=True,
                             squeeze=False)
    for col, beam in enumerate(beams):
        for k, eps in enumerate(args.eps_b):
            t, q, dy, eps_y, _ = runs[beam, eps]
            kw = {'color': f'C{k}', 'lw': 1.0, 'label': rf'$\varepsilon_b$ = {eps:g}',
                  'zorder': len(args.eps_b) - k + 1}       # smaller pre-strains on top
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
    fig.suptitle('step scenario: 0 V, v_max from 1.5 s to 3 s (shaded), 0 V')
    fig.tight_layout()
    path = os.path.join(out, 'step.png')
    fig.savefig(path, dpi=args.dpi)
    plt.close(fig)
    return path
