"""
``det_sim view LOG``: a recorded sim_node log served to Foxglove or Lichtblick over WebSocket.

det_sim_ros.io.log_view plays it (the ``live`` extra); docs/visualization.md has the details.
"""

from __future__ import annotations

import sys
import time

from .. import common

HELP = ('serve a sim_node MCAP log (a file or a run directory) to Foxglove or Lichtblick over '
        "the Foxglove WebSocket protocol, with play, pause, seek and speed (the 'live' extra)")


def add_arguments(parser) -> None:
    """Add the log, --host, --port, --speed, --paused."""
    parser.add_argument('log', nargs='+',
                        help='MCAP file(s) or a log directory (its newest run; the files of a '
                        'run split or reset stay one run)')
    parser.add_argument('--host', default='127.0.0.1',
                        help="address to listen on (default 127.0.0.1; '0.0.0.0': every "
                        'network interface)')
    parser.add_argument('--port', type=int, default=8765,
                        help='TCP port (default 8765; 0: a free port)')
    parser.add_argument('--speed', type=common.positive, default=1.0,
                        help='sim seconds per wall second (default 1; Foxglove can change it); '
                        'capped to what the player can serve, said at the start')
    parser.add_argument('--paused', action='store_true',
                        help='wait for play in Foxglove (default: play when a client subscribes)')


def main(args) -> int:
    """Serve the log until Ctrl-C (exit 0) or until the player fails (the reason; exit 1)."""
    from ...io.live_server import LiveUnavailable
    from ...io.log_view import LogPlayer, MAX_MESSAGES_PER_S
    [run] = common.log_runs_to_use(args.log, 'view')
    try:
        player = LogPlayer(run, host=args.host, port=args.port, speed=args.speed,
                           paused=args.paused)
    except LiveUnavailable as exc:
        raise common.CliError(str(exc)) from None
    log = player.log
    print(f'det_sim view: {len(log.files)} file(s), {log.count} messages, '
          f'{log.duration_ns * 1e-9:.3f} s of sim time, on {player.url}: in Foxglove or '
          f'Lichtblick, Open connection > Foxglove WebSocket > {player.url}; '
          + ('paused' if args.paused else f'plays at x{player.speed:.3g} once a client subscribes')
          + '; Ctrl-C stops', flush=True)
    if args.speed > player.max_speed:
        span_s = (log.end - log.start) * 1e-9
        print(f'det_sim view: --speed {args.speed:g} capped to x{player.max_speed:.3g}, the '
              f'fastest this log plays ({log.count / span_s:.0f} messages per sim second; at '
              f'most {MAX_MESSAGES_PER_S} served per wall second)', flush=True)
    for error in log.errors:
        print(f'det_sim view: warning: {error}', flush=True)
    try:
        reported = False
        while not player.failed:
            time.sleep(0.2)
            if player.finished.is_set() != reported and not player.failed:
                reported = player.finished.is_set()
                if reported:
                    print(f'det_sim view: end of the log ({player.served} messages served); '
                          'seek in Foxglove to play again, Ctrl-C stops', flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        player.stop()
    if player.failed:
        print(f'det_sim view: error: the player stopped: {player.failed}', file=sys.stderr,
              flush=True)
        return 1
    return 0
