"""
The live view's hand-overs between threads (det_sim_ros.io.live_queues): bounded and counted.

A request thread and a worker thread, as the Foxglove server's threads and sim_node's executor
are: the contracts are about what runs, when and how often, counted against what was done.
"""

import threading

from det_sim_ros.io.live_queues import Busy, CallQueue, Pending, SampleQueue
import pytest

SAFETY_S = 30.0   # a safety net: a wait that hits it fails the test


def test_a_full_call_queue_refuses_and_counts_and_runs_only_what_it_took():
    ran = []
    calls = CallQueue(limit=3, timeout_s=SAFETY_S)
    for k in range(3):
        calls.post(lambda k=k: ran.append(k))
    for k in range(3, 10):
        with pytest.raises(Busy, match='busy: 3 client requests are waiting'):
            calls.post(lambda k=k: ran.append(k))
    assert len(calls) == 3 and calls.refused == 7 and calls.most == 3
    calls.run_pending()
    assert ran == [0, 1, 2] and len(calls) == 0
    calls.post(lambda: ran.append('after'))   # room again
    calls.run_pending()
    assert ran[-1] == 'after' and calls.refused == 7


def test_a_call_that_timed_out_never_runs_later():
    applied = []
    calls = CallQueue(limit=8, timeout_s=0.2)   # the worker is not running: nothing answers
    with pytest.raises(TimeoutError, match='nothing was done'):
        calls.call(lambda: applied.append('max_lag = 0.2'))
    assert calls.timed_out == 1 and len(calls) == 0
    calls.run_pending()   # the worker comes back
    assert applied == []


def test_a_call_answers_from_the_worker_thread_with_its_result_or_its_exception():
    calls = CallQueue(limit=8, timeout_s=SAFETY_S)
    stop = threading.Event()
    threads = []

    def worker():
        threads.append(threading.get_ident())
        while not stop.wait(0.005):
            calls.run_pending()
    thread = threading.Thread(target=worker, daemon=True)
    thread.start()
    try:
        assert calls.call(lambda: threading.get_ident()) == threads[0]

        def fails():
            raise ValueError('no such parameter')
        with pytest.raises(ValueError, match='no such parameter'):
            calls.call(fails)
        assert calls.failed == 0   # a call's exception is its caller's answer
    finally:
        stop.set()
        thread.join(SAFETY_S)


def test_posted_work_that_raises_is_counted_handed_over_and_the_rest_runs():
    errors, ran = [], []
    calls = CallQueue(limit=8, timeout_s=SAFETY_S, on_error=errors.append)

    def fails():
        raise KeyError('det9')
    calls.post(lambda: ran.append(1))
    calls.post(fails)
    calls.post(lambda: ran.append(3))
    calls.run_pending()   # (raising here would reach the executor)
    assert ran == [1, 3] and calls.failed == 1
    assert [type(e) for e in errors] == [KeyError]


def test_work_posted_while_the_worker_runs_waits_for_its_next_round():
    ran = []
    calls = CallQueue(limit=8, timeout_s=SAFETY_S)

    def reposts():
        ran.append('first')
        calls.post(reposts)   # a flood that would keep the worker here forever
    calls.post(reposts)
    calls.run_pending()
    assert ran == ['first'] and len(calls) == 1


def test_a_full_sample_queue_drops_the_oldest_and_counts_them():
    samples = SampleQueue(limit=5)
    samples.put([1, 2, 3])
    samples.put([4, 5, 6, 7])
    assert list(samples.take()) == [3, 4, 5, 6, 7]
    assert samples.dropped == 2 and samples.most == 5 and len(samples) == 0
    samples.put(range(8, 20))   # one batch beyond the limit
    assert list(samples.take()) == [15, 16, 17, 18, 19] and samples.dropped == 9


def test_a_call_that_started_and_runs_long_is_pending_and_its_outcome_follows():
    """
    Check that a call the worker started and has not finished is told pending, not failed.

    The worker takes the work at once and runs it until ``release``; the caller, after twice
    its timeout, gets Pending (a TimeoutError that says it goes on); once released, the work's
    outcome reaches ``late`` on the worker thread, and it did run: no answer was untrue.
    """
    calls = CallQueue(limit=8, timeout_s=0.5)
    release, ran, late, answers = threading.Event(), [], [], []

    def work():
        release.wait(SAFETY_S)
        ran.append(threading.current_thread())
        return 'max_lag = 0.2'

    def worker():
        while not ran:
            calls.run_pending()
            release.wait(0.001)

    def caller():
        try:
            answers.append(calls.call(work, late=lambda ok, value: late.append((ok, value))))
        except Exception as exc:  # noqa: BLE001 - what the caller was told, checked below
            answers.append(exc)

    threads = [threading.Thread(target=worker), threading.Thread(target=caller)]
    for thread in threads:
        thread.start()
    threads[1].join(SAFETY_S)
    [answer] = answers
    assert isinstance(answer, Pending) and 'it goes on, its outcome follows' in str(answer)
    assert calls.pending == 1 and late == [] and ran == []
    release.set()
    threads[0].join(SAFETY_S)
    assert ran == [threads[0]] and late == [(True, 'max_lag = 0.2')]
    assert calls.timed_out == 0 and calls.failed == 0
