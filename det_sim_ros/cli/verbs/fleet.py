"""
``det_sim fleet``: the sim_node processes a fleet file lists for this host.

det_sim_ros.ros.fleet describes the file.
"""

from __future__ import annotations

from .. import common

HELP = ('start the sim_nodes of a fleet file on this host (one process per namespace, logs per '
        'node); SIGINT/SIGTERM stop them all')
DESCRIPTION = ('Start the sim_node processes a fleet YAML file lists for this host, each in its '
               'namespace with its log file; forward SIGINT and SIGTERM to all; exit 0 once '
               'every node stopped cleanly. Across hosts, run the same file on every host '
               '(nodes with host: start on that host only). File format: '
               'docs/fleets.md.')


def add_arguments(parser) -> None:
    """Add the fleet file, --host, --log-dir, --stop-timeout."""
    parser.add_argument('file', help='fleet YAML file')
    parser.add_argument('--host', default=None,
                        help="start the nodes for this host name (default: this machine's)")
    parser.add_argument('--log-dir', default=None,
                        help="node logs folder (default: the file's log_dir, else fleet_logs)")
    parser.add_argument('--stop-timeout', type=common.positive, default=20.0,
                        help='s to wait for the nodes to stop before killing them (default: 20)')


def main(args) -> int:
    """Run the fleet until every node stopped; return its exit code."""
    from ...ros.fleet import run_fleet
    return run_fleet(args.file, host=args.host, log_dir=args.log_dir,
                     stop_timeout=args.stop_timeout)
