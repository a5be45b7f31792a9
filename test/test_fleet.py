"""
Fleets (issue 20): ``det_sim fleet FILE`` starts one sim_node process per namespace, forwards
SIGINT/SIGTERM and exits 0 once all stopped cleanly; bad fleet files are one line.
"""

import os
import signal
import subprocess
import sys
import time

import pytest
import yaml

from det_sim_ros.fleet import FleetError, load_fleet
from det_sim_ros.scene import load_scene, scene_to_dict
from conftest import child_env
from test_reliability import finished_logs

WALL_LIMIT = 120.0     # s, a safety net only


def write_fleet(path, nodes, **top):
    path.write_text(yaml.safe_dump({**top, 'nodes': nodes}))
    return str(path)


def start_fleet(fleet_file, *args, env=None):
    """``det_sim fleet`` as a process (its own stdout/stderr file beside the fleet file)."""
    out = fleet_file + '.out'
    with open(out, 'w') as stream:
        proc = subprocess.Popen([sys.executable, '-m', 'det_sim_ros.cli', 'fleet', fleet_file,
                                 *args], stdout=stream, stderr=subprocess.STDOUT,
                                env=env or child_env(PYTHONUNBUFFERED='1'))
    proc.out = out
    return proc


def text(path):
    with open(path, encoding='utf-8', errors='replace') as stream:
        return stream.read()


def wait_for_text(proc, needle, count=1):
    deadline = time.monotonic() + WALL_LIMIT
    while text(proc.out).count(needle) < count:
        assert proc.poll() is None, text(proc.out)
        assert time.monotonic() < deadline, text(proc.out)
        time.sleep(0.05)


@pytest.mark.parametrize('stop', [signal.SIGINT, signal.SIGTERM])
def test_fleet_starts_its_nodes_and_forwards_the_stop(tmp_path, stop):
    """Two nodes (real-time and lockstep, scene override): both run in their namespaces with
    their own log file; the signal to the fleet stops both, exit 0, MCAP logs finished."""
    fleet_file = write_fleet(tmp_path / 'fleet.yaml', [
        {'namespace': '/a', 'overrides': {'physics.Rs': '1e3'}},
        {'namespace': '/lab/b', 'mode': 'lockstep', 'scene': 'plate'},
    ], defaults={'params': {'info_period': 0.0}}, log_dir='logs')
    proc = start_fleet(fleet_file)
    try:
        wait_for_text(proc, ' running', 2)
        proc.send_signal(stop)
        assert proc.wait(timeout=WALL_LIMIT) == 0, text(proc.out)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert 'all 2 node(s) stopped cleanly' in text(proc.out)
    a, b = text(tmp_path / 'logs' / 'a.log'), text(tmp_path / 'logs' / 'lab_b.log')
    assert '[a.sim_node]' in a and 'real-time' in a and "scene 'default'" in a
    assert '[lab.b.sim_node]' in b and 'lockstep' in b and "scene 'plate'" in b
    for name in ('a', 'lab_b'):
        assert len(finished_logs(str(tmp_path / 'logs' / name))) == 1
    params = yaml.safe_load((tmp_path / 'logs' / 'a.params.yaml').read_text())
    assert params['/**']['ros__parameters']['physics']['Rs'] == 1e3


def test_a_node_that_cannot_start_stops_the_fleet(tmp_path):
    """A node refusing its parameters (one line, exit 1) stops the others: the fleet exits 1
    and names the node and its reason."""
    fleet_file = write_fleet(tmp_path / 'fleet.yaml', [
        {'namespace': '/good', 'params': {'info_period': 0.0}},
        {'namespace': '/bad', 'params': {'diagnostics_period': -1.0}},
    ])
    proc = start_fleet(fleet_file)
    try:
        assert proc.wait(timeout=WALL_LIMIT) == 1, text(proc.out)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out = text(proc.out)
    assert '/bad exited with code 1' in out and 'diagnostics_period' in out, out
    assert 'Traceback' not in out + text(tmp_path / 'fleet_logs' / 'bad.log')


BAD_FLEETS = [
    ({'nodes': []}, 'nodes: must be a non-empty list'),
    ({'nodes': [{'namespace': 'a'}]}, "namespace: expected /name"),
    ({'nodes': [{'namespace': '/a'}, {'namespace': '/a'}]}, 'namespace used twice'),
    ({'nodes': [{'namespace': '/a', 'mode': 'fast'}]}, 'mode: one of'),
    ({'nodes': [{'namespace': '/a', 'params': {'physics.Rs': 1.0}}]},
     "unknown parameter 'physics.Rs' (scene keys go in overrides:)"),
    ({'nodes': [{'namespace': '/a', 'overrides': {'physics.Rs': -1.0}}]}, 'node /a: '),
    ({'nodes': [{'namespace': '/a', 'scene': 'nowhere.yaml'}]}, 'node /a: '),
    ({'nodes': [{'namespace': '/a', 'colour': 'red'}]}, "unknown key 'colour'"),
    ({'nodes': [{'namespace': '/a', 'params': {'mode': 'lockstep'}}]}, 'set the mode with'),
    ({'nodes': [{'namespace': '/a', 'host': 'elsewhere'}]}, 'no node runs on host'),
]


@pytest.mark.parametrize('fleet,message', BAD_FLEETS)
def test_bad_fleet_file_is_one_line_and_starts_nothing(tmp_path, capsys, fleet, message):
    from det_sim_ros import cli
    path = tmp_path / 'fleet.yaml'
    path.write_text(yaml.safe_dump(fleet))
    assert cli.main(['fleet', str(path), '--host', 'here']) == 2
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0 and err.startswith('det_sim: error: ') and message in err, err
    assert not (tmp_path / 'fleet_logs').exists()


def test_host_filter_and_relative_paths(tmp_path):
    """The same file on every host: a node with host: starts only there; relative scene and
    log paths are relative to the fleet file."""
    (tmp_path / 'my_scene.yaml').write_text(yaml.safe_dump(scene_to_dict(load_scene('default'))))
    path = write_fleet(tmp_path / 'fleet.yaml', [
        {'namespace': '/everywhere'},
        {'namespace': '/one', 'host': 'h1', 'scene': 'my_scene.yaml'},
        {'namespace': '/two', 'host': 'h2'},
    ], log_dir='out')
    on_h1 = load_fleet(path, host='h1')
    assert [n.namespace for n in on_h1] == ['/everywhere', '/one']
    assert on_h1[1].scene == str(tmp_path / 'my_scene.yaml')
    assert on_h1[1].log_file == str(tmp_path / 'out' / 'one.log')
    assert [n.namespace for n in load_fleet(path)] == ['/everywhere', '/one', '/two']
    with pytest.raises(FleetError, match='not valid YAML'):
        (tmp_path / 'broken.yaml').write_text('nodes: [')
        load_fleet(str(tmp_path / 'broken.yaml'))


def test_shipped_fleet_example_loads():
    here = os.path.dirname(os.path.abspath(__file__))
    nodes = load_fleet(os.path.join(here, '..', 'config', 'fleet.yaml'))
    assert [n.mode for n in nodes] == ['real_time', 'real_time', 'lockstep']
