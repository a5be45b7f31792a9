"""
``det_sim linearize``: the linear model (A, B, C, D) at an equilibrium.

Poles, damping, natural frequencies, DC gains (JSON and text) and a Bode plot.
"""

from __future__ import annotations

import json
import math
import os

from .. import common

HELP = ('linear model (A, B, C, D) at an equilibrium: poles, damping, natural frequencies, DC '
        'gains, Bode plot')


def add_arguments(parser) -> None:
    """Add the scene options, --voltage, --branch, --json."""
    common.add_scene_arguments(parser)
    parser.add_argument('--voltage', type=common.float_list, default=[0.0],
                        help='DET voltage(s), V: one for all DETs or one per DET (default: 0)')
    parser.add_argument('--branch', default='buckled+',
                        help='equilibrium branch: buckled+ (default), buckled- or straight')
    parser.add_argument('--json', action='store_true', help='print the result as JSON')


def main(args) -> int:
    """Linearize, write linearization.json (and bode.png), print the result."""
    from ...physics.linearize import linearize
    scene = common.base_scene(args)
    voltage = args.voltage[0] if len(args.voltage) == 1 else args.voltage
    lin = linearize(scene, voltage, args.branch)
    poles = lin.poles()
    out = common.out_dir(args)
    report = _report(args.scene, lin, poles)
    json_path = os.path.join(out, 'linearization.json')
    with open(json_path, 'w', encoding='utf-8') as stream:
        json.dump(report, stream, indent=1)
    files = [json_path]
    plt = common.pyplot(args)
    if plt is not None:
        files.append(_plot_bode(plt, lin, poles, args, out))
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    _print_table(args.scene, lin, poles)
    common.print_written(files)
    return 0


def _report(scene_name, lin, poles) -> dict:
    wn, zeta = lin.natural_frequency(poles), lin.damping(poles)
    gain = lin.dc_gain()
    return {
        'scene': scene_name, 'branch': lin.branch, 'voltage_V': lin.u0.tolist(),
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


def _print_table(scene_name, lin, poles) -> None:
    wn, zeta = lin.natural_frequency(poles), lin.damping(poles)
    gain = lin.dc_gain()
    n_in = len(lin.input_names)
    print(f"{scene_name}: {lin.branch} equilibrium at {', '.join(f'{v:g}' for v in lin.u0)} V: "
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


def _plot_bode(plt, lin, poles, args, out):
    """Plot |G| and phase of dy_i/V_i and q_i/V_i (each DET's own input; at most 6 DETs)."""
    import numpy as np
    rates = np.abs(poles[np.abs(poles) > 0])
    lo = max(rates.min() / 10.0 if rates.size else 0.1, 1e-2)
    hi = rates.max() * 10.0 if rates.size else 1e4
    omega = np.logspace(np.log10(lo), np.log10(hi), 600)
    G = lin.frequency_response(omega)
    n = len(lin.input_names)
    fig, (ax_m, ax_p) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    f = omega / (2 * math.pi)
    drawn = 0
    for i in range(min(n, 6)):
        for r, style in ((i, '-'), (n + i, '--')):
            g = G[:, r, i]
            if not np.any(np.abs(g) > 0):       # e.g. a DET at 0 V: force ~ V^2, no gain
                continue
            label = f'{lin.output_names[r]} / V[{lin.input_names[i]}]'
            ax_m.loglog(f, np.abs(g), style, lw=1.2, label=label)
            ax_p.semilogx(f, np.degrees(np.unwrap(np.angle(g))), style, lw=1.2)
            drawn += 1
    ax_m.set_ylabel('|G| (m/V)')
    ax_p.set_ylabel('phase (deg)')
    ax_p.set_xlabel('frequency (Hz)')
    for ax in (ax_m, ax_p):
        ax.grid(alpha=0.3, which='both')
    if drawn:
        ax_m.legend(fontsize=8)
    else:   # every DET at 0 V: an empty plot says why
        ax_m.text(0.5, 0.5, 'no gain at 0 V: the force goes as V^2', ha='center',
                  va='center', transform=ax_m.transAxes)
    ax_m.set_title(f'{args.scene}: linearized at {", ".join(f"{v:g}" for v in lin.u0)} V, '
                   f'{lin.branch}')
    fig.tight_layout()
    path = os.path.join(out, 'bode.png')
    fig.savefig(path, dpi=args.dpi)
    plt.close(fig)
    return path
