"""
``det_sim predictability``: is a run's path a result? A perturbed twin beside it, offline.

For a scene and a scenario input (``--input pwm``, ``switching``, ``step``) or for a sim_node
log (``--log``: its scene and its commands, re-simulated), runs the scene and its twin
(det_sim_ros.analysis.predictability) and writes the twin's distance per sample
(predictability.csv) and a plot marking where the path is not robust (predictability.png).
One line says whether it is robust and from when not; ``--check`` exits 1 when it is not.
"""

from __future__ import annotations

import os

from .. import common

HELP = 'where a run stops being robust: a perturbed twin beside it (scene + input, or a log)'
INPUTS = ('pwm', 'switching', 'step')


def add_arguments(parser) -> None:
    """Add the scene options, the input or log, the perturbation and --check."""
    common.add_scene_arguments(parser)
    parser.add_argument('--input', choices=INPUTS, default='pwm',
                        help="scenario input: 'pwm' (10 Hz PWM at v_max from 0.5 s, duty "
                             "30-70 %%), 'switching' (square wave), 'step' (default: pwm)")
    parser.add_argument('--hz', type=common.positive, default=None,
                        help='carrier frequency of pwm / switching, Hz (default 10 / 2)')
    parser.add_argument('--t-end', type=common.positive, default=None,
                        help='end time, s (default: 2.5; step 4.5; a log: its length)')
    parser.add_argument('--log', default=None,
                        help='a sim_node log (file or directory: its newest run): its scene '
                             'and commands instead of --scene and --input')
    parser.add_argument('--parameter', default='m',
                        help="the twin's perturbed physics parameter (default: m)")
    parser.add_argument('--relative', type=float, default=1e-6,
                        help='its relative change (default: 1e-6)')
    parser.add_argument('--tolerance-factor', type=common.positive, default=0.9,
                        help="the twin's tolerance over the run's (default: 0.9)")
    parser.add_argument('--limit', type=common.positive, default=0.05,
                        help='distance beyond which the path is not robust, a fraction of '
                             'the stroke (default: 0.05)')
    parser.add_argument('--check', action='store_true',
                        help='exit 1 when the path is not robust (for scripts and CI)')


def _scene_and_input(args):
    """Return (scene, volts, t_end, label) from --log, or the scene options and --input."""
    from ...analysis.scenarios import pwm_voltage, step_voltage, switching_voltage
    if args.log:
        from ...calibration.logs import read_log
        (files,) = common.log_runs_to_use([args.log], 'predictability')
        measurement = read_log(files[0])
        t_end = args.t_end or measurement.periods * measurement.dt
        return measurement.scene, measurement.volts, t_end, os.path.basename(files[0])
    scene = common.base_scene(args)
    if not common.user_set(args, 'scene.initial_state', 'initial_state'):
        scene = scene.replace(**{'scene.initial_state': 'released'})   # as the scenarios
    v_max = scene.physics.v_max
    if args.input == 'step':
        return scene, step_voltage(v_max), args.t_end or 4.5, 'step'
    if args.input == 'switching':
        hz = args.hz or 2.0
        return scene, switching_voltage(v_max, hz), args.t_end or 2.5, f'{hz:g} Hz switching'
    hz = args.hz or 10.0
    return scene, pwm_voltage(v_max, hz), args.t_end or 2.5, f'{hz:g} Hz PWM'


def main(args) -> int:
    """Run the scene and its twin; print the verdict, write the CSV (and the PNG)."""
    from ...analysis.predictability import Perturbation, predictability
    try:   # (a perturbation that cannot be: bad input, one line, exit 2)
        perturbation = Perturbation(args.parameter, args.relative, args.tolerance_factor)
    except ValueError as exc:
        raise common.CliError(str(exc)) from None
    scene, volts, t_end, label = _scene_and_input(args)
    result = predictability(scene, volts, t_end, perturbation, args.limit)
    print(f'{label}, {scene.beam} beam, eps_b {scene.eps_b:g}: {result.summary()}')
    out = common.out_dir(args)
    q, y = _first_det(result.run, 'q'), _first_det(result.run, 'y')
    files = [common.write_csv(
        os.path.join(out, 'predictability.csv'), ['t_s', 'v_V', 'q_m', 'q_twin_m', 'y_m',
                                                  'y_twin_m', 'twin_distance'],
        zip(result.t, result.run.u[:, 0], result.run[q], result.twin[q], result.run[y],
            result.twin[y], result.distance))]
    plt = common.pyplot(args)
    if plt is not None:
        files.append(_plot(plt, result, label, scene, os.path.join(out, 'predictability.png'),
                           args.dpi))
    common.print_written(files)
    return 1 if args.check and not result.robust else 0


def _first_det(run, base: str) -> str:
    """Return the output name of ``base`` for the first DET ('q', or 'q[left]' for several)."""
    return base if base in run.outputs else next(n for n in run.outputs
                                                 if n.startswith(base + '['))


def _plot(plt, result, label, scene, path, dpi) -> str:
    """Plot q of the run and its twin, the distance, and shade the stretches not robust."""
    t = result.t
    q = _first_det(result.run, 'q')
    fig, (ax_q, ax_d) = plt.subplots(2, 1, sharex=True, figsize=(9, 5.5))
    ax_q.plot(t, result.run[q] * 1e3, lw=0.8, label='run')
    ax_q.plot(t, result.twin[q] * 1e3, lw=0.8, ls='--',
              label=f'twin ({result.perturbation.describe()})')
    ax_q.set_ylabel('q (mm)')
    ax_q.legend(loc='upper right', fontsize='small')
    ax_d.semilogy(t, result.distance * 100, lw=0.8, color='k')
    ax_d.axhline(result.limit * 100, color='r', lw=0.8, ls=':', label='limit')
    ax_d.set_ylabel('twin distance (% of stroke)')
    ax_d.set_xlabel('t (s)')
    ax_d.legend(loc='lower right', fontsize='small')
    for ax in (ax_q, ax_d):
        for start, end in result.stretches:
            ax.axvspan(start, t[-1] if end is None else end, color='r', alpha=0.12, lw=0)
    verdict = ('robust' if result.robust
               else f'not robust from {result.robust_until:.3f} s (shaded)')
    fig.suptitle(f'{label}, {scene.beam} beam, eps_b {scene.eps_b:g}: {verdict}',
                 fontsize='medium')
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
