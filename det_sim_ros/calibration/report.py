"""
A fit's outputs: the text report, the fitted scene file and the plot of measured vs simulated.

The scene file is a complete scene (the base scene with the fitted values), loadable as it is
by ``load_scene`` and by sim_node (``-p scene_file:=fitted.yaml``). The report and the PNG go
beside it: ``fitted.yaml`` -> ``fitted_report.txt``, ``fitted.png``.
"""

from __future__ import annotations

import math
import os

import numpy as np

from .intervals import MAX_CORRELATION, MAX_DIRECTION_SE, RCOND
from ..scenes.outputs import fit_channels

__all__ = ['report_text', 'write_outputs', 'scene_yaml', 'output_paths']

# measured channel -> (scale from SI, unit) of the residuals and plots
_UNIT_SCALE = {name: (row.fit.report_scale, row.fit.report_unit)
               for name, row in fit_channels().items()}


def _channel_rows(result) -> list:
    lines = ['residual RMS per channel (measured - simulated):',
             f"  {'log':<34} {'channel':<8} {'noise':>10} {'start':>10} {'fitted':>10}"]
    for key, after in result.rms_after.items():
        source, channel = key
        scale, unit = _UNIT_SCALE.get(channel, (1.0, ''))
        noise = float(np.mean(result.noise[key]))
        name = os.path.basename(source)
        lines.append(f'  {name[-34:]:<34} {channel:<8} {noise * scale:>10.4g} '
                     f'{result.rms_before[key] * scale:>10.4g} {after * scale:>10.4g}  {unit}')
    return lines


def _interval(e) -> str:
    if not math.isfinite(e.se):
        return 'not determined'
    return f'[{e.lower95:.5g}, {e.upper95:.5g}]'


def _parameter_rows(result) -> list:
    lines = ['parameters (95 % intervals from the Jacobian at the optimum, scaled by the '
             'residual variance):',
             f"  {'name':<8} {'start':>11} {'fitted':>11} {'std err':>11} {'(%)':>7}  "
             f"{'95 % interval':<26} unit"]
    for e in result.estimates:
        rel = f'{100 * e.relative_se:.2f}' if math.isfinite(e.relative_se) else '-'
        se = f'{e.se:.4g}' if math.isfinite(e.se) else '-'
        lines.append(f'  {e.name:<8} {e.start:>11.5g} {e.value:>11.5g} {se:>11} {rel:>7}  '
                     f'{_interval(e):<26} {e.unit}')
    return lines


def _correlation_rows(result) -> list:
    names = [e.name for e in result.estimates]
    lines = ['correlation matrix:', '  ' + ' ' * 8 + ''.join(f'{n:>9}' for n in names)]
    for name, row in zip(names, result.correlation):
        lines.append(f'  {name:<8}' + ''.join('        -' if not np.isfinite(c) else f'{c:>9.3f}'
                                              for c in row))
    return lines


def _warnings(result) -> list:
    lines = []
    for e in result.estimates:
        for flag in e.flags:
            lines.append(f'  WARNING {e.name}: {flag}')
    if not result.converged:
        lines.append(f'  WARNING the fit {result.message}')
    if lines:
        lines.insert(0, f'identifiability (flagged: a singular value below {RCOND:g} x the '
                     f'largest or a direction with standard error above {MAX_DIRECTION_SE:g} in '
                     f'log scale, or |correlation| > {MAX_CORRELATION:g}):')
    return lines


def _pass_rows(result) -> list:
    lines = ['model level of each pass (fidelity, Ritz terms, integrator tolerance):']
    for p in result.passes:
        lines.append(f'  {p.role}: {p.level}: {p.work}; {p.simulate_calls} simulate() calls in '
                     f'{p.wall_time:.1f} s ({p.parallel})')
    return lines if result.passes else []


def report_text(result) -> str:
    """Return the report: residuals before and after, estimates, correlations, warnings."""
    status = 'converged' if result.converged else 'DID NOT CONVERGE'
    head = [f'det_sim fit: {status} ({result.message})',
            f'{len(result.traces)} log(s), {result.samples} samples, {len(result.estimates)} '
            f'parameter(s), {result.simulate_calls} simulate() calls in {result.wall_time:.1f} s '
            f'({result.parallel})',
            f'misfit: the residuals are {math.sqrt(result.residual_variance):.3g} times the '
            'noise (RMS; 1 = the model explains the log down to its noise; residual variance '
            f'{result.residual_variance:.4g} on {result.dof} degrees of freedom)']
    names = ', '.join(e.name for e in result.estimates)
    starts = ['starting points tried, first on the signals averaged over 50 ms (which hides the '
              f'ringing); ({names}) -> misfit after a few steps (a start on the wrong side of '
              'the snap-through stays far off and is dropped):']
    for n, s in enumerate(result.starts, start=1):
        values = ', '.join(f'{v:.4g}' for v in s.start)
        starts.append(f'  {n}: ({values}) -> {_misfit(s.cost, result.samples)} after '
                      f'{s.evaluations} runs')
    blocks = [head, _pass_rows(result), _channel_rows(result), _parameter_rows(result),
              _correlation_rows(result), starts, _warnings(result)]
    return '\n\n'.join('\n'.join(block) for block in blocks if block) + '\n'


def _misfit(cost: float, samples: int) -> str:
    """Return a cost 0.5 |r|^2 as the residuals' RMS in noise units ('12 x noise')."""
    return f'{math.sqrt(2.0 * cost / max(samples, 1)):.3g} x noise'


def rounded(value: float, se: float) -> float:
    """
    Return ``value`` rounded to the digits its standard error leaves meaningful.

    Two significant digits of the standard error are kept (1299999.9999994477 with a standard
    error of 2.1e4 -> 1300000.0); without a finite one, six significant digits.
    """
    if not math.isfinite(value) or value == 0.0:
        return value
    if not math.isfinite(se) or se <= 0.0:
        return float(f'{value:.6g}')
    return round(value, 1 - math.floor(math.log10(se)))


def scene_yaml(result) -> str:
    """Return the fitted scene as a complete scene file (sim_node: ros__parameters: ...)."""
    import yaml
    from ..scenes.scene import scene_to_dict
    fitted = ', '.join(f'{e.name} = {e.value:.6g}' for e in result.estimates)
    data = scene_to_dict(result.scene, wrap=True)
    section = data['sim_node']['ros__parameters']
    for e in result.estimates:   # the fitted values with the digits their intervals give
        group, _, name = e.key.rpartition('.')
        table = section.get(group) if group else section
        if isinstance(table, dict) and isinstance(table.get(name), float):
            table[name] = rounded(table[name], e.se)
    return (f'# det_sim fit: {fitted}\n# report: see the _report.txt file beside this one\n'
            + yaml.safe_dump(data, sort_keys=False))


def output_paths(path: str) -> tuple:
    """Return (scene, report, png) paths for the scene path ``path``."""
    stem = os.path.splitext(path)[0]
    return path, f'{stem}_report.txt', f'{stem}.png'


def write_outputs(result, path: str, plot: bool = True) -> list:
    """Write the scene file, the report and (matplotlib permitting) the PNG; return the paths."""
    scene_path, report_path, png_path = output_paths(path)
    folder = os.path.dirname(os.path.abspath(scene_path))
    os.makedirs(folder, exist_ok=True)
    with open(scene_path, 'w', encoding='utf-8') as stream:
        stream.write(scene_yaml(result))
    with open(report_path, 'w', encoding='utf-8') as stream:
        stream.write(report_text(result))
    written = [scene_path, report_path]
    if plot and draw(result, png_path):
        written.append(png_path)
    return written


def draw(result, path: str, dpi: int = 80) -> bool:
    """Draw measured vs simulated (start, fitted) per log and channel; False without matplotlib."""
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    panels = [(trace, name, data) for trace in result.traces
              for name, data in trace['channels'].items()][:8]
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 2.6 * len(panels)), squeeze=False)
    for ax, (trace, name, (index, measured, before, after)) in zip(axes[:, 0], panels):
        scale, unit = _UNIT_SCALE.get(name, (1.0, ''))
        t = trace['t']
        ax.plot(t[index], measured[:, 0] * scale, '.', ms=1.5, color='0.6', label='measured')
        for run, style, label in ((before, '--', 'start'), (after, '-', 'fitted')):
            if run is not None:
                ax.plot(t, run[:, 0] * scale, style, lw=1.0, label=label)
        ax.set_ylabel(f'{name} ({unit})')
        ax.set_title(os.path.basename(trace['source']), fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc='upper right')
    axes[-1, 0].set_xlabel('t (s)')
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return True
