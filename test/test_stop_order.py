"""
Test what follows a stop: the log is finished first, then the teardown is bounded in time.

The process tests in test_reliability.py stop real nodes; these check the order and the bound
themselves, with a recorder and an executor that only note what happens to them.
"""

import faulthandler
import subprocess
import sys
import textwrap
import types

from det_sim_ros.ros import spinning
import pytest

pytestmark = pytest.mark.ros


class _Recorder:
    paths = ['run.mcap']

    def __init__(self, events):
        self.events = events

    def close(self):
        self.events.append('log finished')


class _Executor:
    def __init__(self, events):
        self.events = events

    def add_node(self, node):
        pass

    def spin_once(self, timeout_sec):
        raise AssertionError('the stop was requested before spinning')

    def remove_node(self, node):
        self.events.append('executor teardown')

    def shutdown(self, timeout_sec):
        self.events.append('executor shutdown')


class _Node:
    context = None
    steps_total = 0
    simulator = types.SimpleNamespace(t=0.0)

    def __init__(self, events):
        self.recorder = _Recorder(events)
        self.events = events

    def get_logger(self):
        return types.SimpleNamespace(info=lambda text: self.events.append('stop line'))


class _Stop:
    requested = 15

    def __init__(self, events):
        self.events = events

    def end(self):
        self.events.append('teardown bounded')


def test_the_log_is_finished_before_the_middleware_is_taken_down(monkeypatch):
    events = []
    monkeypatch.setattr(spinning, 'make_executor', lambda context: _Executor(events))
    spinning.spin_until_stopped(_Node(events), _Stop(events))
    assert events == ['log finished', 'stop line', 'teardown bounded', 'executor teardown',
                      'executor shutdown']


def test_the_start_up_is_frozen_out_of_the_garbage_collector_before_spinning(monkeypatch):
    """
    Check that the objects made before the spin are frozen (gc.freeze) once spinning starts.

    A full collection then walks only what the run made: what the start-up made was measured
    to cost a 250 ms stall beside a busy core. (The freeze is undone after: the test process
    goes on.)
    """
    import gc
    events, frozen = [], []
    monkeypatch.setattr(spinning, 'make_executor', lambda context: _Executor(events))
    monkeypatch.setattr(_Stop, 'end', lambda self: frozen.append(gc.get_freeze_count()))
    gc.unfreeze()
    try:
        spinning.spin_until_stopped(_Node(events), _Stop(events))
    finally:
        gc.unfreeze()
    assert frozen and frozen[0] > 1000   # every module, class and function loaded so far


def test_the_end_of_a_run_bounds_its_teardown_until_leaving(monkeypatch):
    armed = []
    monkeypatch.setattr(spinning, 'limit_teardown', lambda: armed.append(True))
    with spinning.StopSignals() as stop:
        stop.end()
        assert armed and not stop.preparing
    faulthandler.cancel_dump_traceback_later()


def _run(code):
    return subprocess.run([sys.executable, '-c', textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=120)


def test_a_teardown_that_hangs_ends_the_process_with_its_stacks():
    result = _run("""
        import time
        from det_sim_ros.ros.spinning import limit_teardown
        limit_teardown(0.2)
        time.sleep(100)            # a teardown that never ends
        print('not reached')
    """)
    assert result.returncode == 1
    assert 'not reached' not in result.stdout
    assert 'Timeout (' in result.stderr      # (what test_reliability recognises as the bound)
    assert 'most recent call first' in result.stderr and 'line 5' in result.stderr


@pytest.mark.parametrize('hang', [False, True])
def test_leaving_stop_signals_cancels_the_bound(hang):
    result = _run(f"""
        import time
        from det_sim_ros.ros.spinning import limit_teardown, StopSignals
        with StopSignals():
            limit_teardown(0.2)
            time.sleep(0.5 if {hang} else 0.0)
        time.sleep(0.5)            # an in-process caller goes on
        print('went on')
    """)
    assert result.returncode == (1 if hang else 0), result.stderr
    assert ('went on' in result.stdout) is not hang


def test_a_name_refused_while_running_says_fatal_before_its_stop_line(monkeypatch):
    """Check a claim heard after the start's wait: the FATAL line, then the stop line; code 1."""
    events = []
    monkeypatch.setattr(spinning, 'make_executor', lambda context: _Executor(events))
    node = _Node(events)
    node.context = types.SimpleNamespace(ok=lambda: True)
    node.name_claim = types.SimpleNamespace(refusal='another node named /sim_node is running')
    node.get_logger = lambda: types.SimpleNamespace(
        info=lambda text: events.append('stop line'),
        fatal=lambda text: events.append(f'FATAL {text}'))
    stop = _Stop(events)
    stop.requested = 0
    assert spinning.spin_until_stopped(node, stop) == 1
    assert events == ['log finished', 'FATAL cannot run: another node named /sim_node is running',
                      'stop line', 'teardown bounded', 'executor teardown', 'executor shutdown']
