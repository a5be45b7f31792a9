"""
The screenful summary of ``det_sim plot``: one row per quantity over all its channels.

A log of many DETs (an array of 100 has some 600 channels) is summed up per quantity: the
lowest and highest value over every channel and sample (with the channel it belongs to), and
the final values' minimum, median and maximum over the channels. Logs of up to
:data:`PER_CHANNEL_LIMIT` DETs keep one row per channel (det_sim_ros.io.logplot.summary).
"""

from __future__ import annotations

__all__ = ['PER_CHANNEL_LIMIT', 'screen_summary']

PER_CHANNEL_LIMIT = 4   # DETs; beyond this the screen shows one row per quantity


def _row(label: str, names, values) -> str:
    """Return one quantity's row; ``values``: (samples, channels)."""
    import numpy as np
    if values.size == 0:
        return f'{label:<28} {len(names):>8} {0:>8}'
    low = np.unravel_index(np.argmin(values), values.shape)[1]
    high = np.unravel_index(np.argmax(values), values.shape)[1]
    final = values[-1]
    return (f'{label:<28} {len(names):>8} {values.shape[0]:>8} '
            f'{values[:, low].min():>11.5g} {names[low]:<7} '
            f'{values[:, high].max():>11.5g} {names[high]:<7} '
            f'{final.min():>11.5g} {float(np.median(final)):>11.5g} {final.max():>11.5g}')


def screen_summary(data, full_text: str) -> str:
    """
    Return the summary to print: ``full_text`` for a few DETs, else one row per quantity.

    :param data: det_sim_ros.io.logplot.LogData.
    :param full_text: its per-channel summary (whose first two lines, the log and the
        commands, are kept).
    """
    if len(data.det_names) <= PER_CHANNEL_LIMIT:
        return full_text
    log_line, dets_line = full_text.splitlines()[:2]
    names = data.det_names
    _, _, rest = dets_line.partition('; sim time')
    lines = [
        log_line, f'DETs: {names[0]}, {names[1]} … {names[-1]} ({len(names)}); sim time' + rest,
        f"{'quantity':<28} {'channels':>8} {'samples':>8} {'min':>11} {'(where)':<7} "
        f"{'max':>11} {'(where)':<7} {'final: min':>11} {'median':>11} {'max':>11}",
        _row('voltage (V)', data.det_names, data.voltage)]
    lines += [_row(f'{ch.title} ({ch.unit})', ch.names, ch.values) for ch in data.channels]
    lines.append('(one row per quantity over its channels; min and max over every sample; '
                 'final: over the channels; --all for every channel)')
    return '\n'.join(lines) + '\n'
