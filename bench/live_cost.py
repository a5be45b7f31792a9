"""
CPU cost of the live view (Foxglove WebSocket): off, on without a client, on with one client.

Five sim_nodes run in this process, default scene, the MCAP log and 30 Hz markers on as a user
runs them; free run (the node's cheapest mode per period, so the live view's largest share) or,
with --real-time, at 1 kHz as a user watching runs them: ``off`` (live.enabled false), ``off2``
(the same again: an A/A control, the method's own noise on this host), ``idle`` (live on, no
client), ``watched`` (live on, one client in another process subscribed to every channel,
reading and counting what it gets) and ``watched_100Hz`` (the same with live.rate_hz 100: a
tenth of the 1 kHz samples). Only one node runs at a time (the others paused), in blocks of
``--block-s`` wall seconds, the five in a random order per round, so the host's drift hits all
alike. Node CPU = this process's CPU time (all threads: DDS, log writer, the live view's
sender and server threads) per control period in each block; reported: per state the median
over rounds of its ratio to ``off`` in the same round, with the quartiles, the CPU per period
of ``off`` and the executor thread's share (a server's threads may still send a backlog during
the next block, of any state, which pulls the ratios towards 1).

    python bench/live_cost.py [--rounds 20] [--block-s 0.5] [--real-time] [--quick]
"""

import argparse
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time

CLIENT = """
import asyncio, json, os, signal, sys, time
import websockets

got = 0
signal.signal(signal.SIGTERM, lambda *_: (print(got, flush=True), os._exit(0)))

async def main(port, seconds):
    global got
    async with websockets.connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1'],
                                  max_size=None) as ws:
        channels, end = set(), None
        while end is None or time.monotonic() < end:
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.5)
            except asyncio.TimeoutError:
                continue
            except websockets.ConnectionClosed:
                break
            if isinstance(frame, str):
                message = json.loads(frame)
                if message['op'] == 'advertise':
                    new = [c['id'] for c in message['channels'] if c['id'] not in channels]
                    channels.update(new)
                    await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                        {'id': c, 'channelId': c} for c in new]}))
                    end = time.monotonic() + seconds
            elif frame[0] == 1:
                got += 1
    print(got, flush=True)

asyncio.run(main(int(sys.argv[1]), float(sys.argv[2])))
"""


def start(name, live, log_dir, rate_hz=0.0, real_time=False):
    """Start a free-running sim_node (its own context and executor); return (node, executor)."""
    import rclpy
    from rclpy.parameter import Parameter
    from det_sim_ros.ros.node import make_executor, SimNode
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = SimNode(context=context, namespace=name, parameter_overrides=[
        Parameter('real_time', value=real_time), Parameter('info_period', value=0.0),
        Parameter('start_paused', value=True),
        Parameter('log.path', value=os.path.join(log_dir, name)),
        Parameter('live.enabled', value=live), Parameter('live.port', value=0),
        Parameter('live.rate_hz', value=rate_hz),
        Parameter('allow_duplicate_name', value=True)])
    executor = make_executor(context)
    executor.add_node(node)
    return node, executor


def spin_block(node, executor, seconds):
    """
    Run one node (resumed, then paused again) for ``seconds`` of wall time.

    Return (CPU s, executor thread CPU s, periods run).
    """
    k0, c0, t0 = node.simulator.k, time.process_time(), time.thread_time()
    node.set_paused(False)
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        executor.spin_once(timeout_sec=0.05)
    node.set_paused(True)
    return time.process_time() - c0, time.thread_time() - t0, node.simulator.k - k0


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('--rounds', type=int, default=20)
    parser.add_argument('--block-s', type=float, default=0.5)
    parser.add_argument('--real-time', action='store_true',
                        help='the nodes in real time at 1 kHz (as a user watching runs them) '
                        'instead of free run')
    parser.add_argument('--quick', action='store_true',
                        help='two rounds of 0.05 s blocks, a 0.05 s warm-up (a smoke run)')
    args = parser.parse_args()
    warm_up = 0.5
    if args.quick:
        args.rounds, args.block_s, warm_up = 2, 0.05, 0.05
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    states = ('off', 'off2', 'idle', 'watched', 'watched_100Hz')
    watched = ('watched', 'watched_100Hz')
    with tempfile.TemporaryDirectory() as log_dir:
        nodes = {state: start(state, state not in ('off', 'off2'), log_dir,
                              100.0 if state == 'watched_100Hz' else 0.0, args.real_time)
                 for state in states}
        seconds = args.rounds * len(states) * args.block_s + 30.0
        clients = {state: subprocess.Popen([sys.executable, '-c', CLIENT,
                                            str(nodes[state][0].live.port), str(seconds)],
                                           stdout=subprocess.PIPE, text=True)
                   for state in watched}
        deadline = time.monotonic() + 30.0
        while not all(nodes[state][0].live.watched for state in watched) \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        for node, executor in nodes.values():     # warm up each
            spin_block(node, executor, warm_up)
        rng = random.Random(1)
        per_period = {state: [] for state in states}
        periods = dict.fromkeys(states, 0)
        executor_cpu = dict.fromkeys(states, 0.0)
        for _ in range(args.rounds):
            order = list(states)
            rng.shuffle(order)
            for state in order:
                cpu, main_cpu, n = spin_block(*nodes[state], args.block_s)
                per_period[state].append(cpu / n)
                periods[state] += n
                executor_cpu[state] += main_cpu
        received = {}
        for state, client in clients.items():
            client.terminate()
            received[state] = client.communicate(timeout=10)[0].strip() or '?'
        for node, executor in nodes.values():
            executor.shutdown()
            node.destroy_node()
    off = per_period['off']
    mode = 'real time' if args.real_time else 'free run'
    print(f'live view cost, default scene, {mode}, MCAP log and 30 Hz markers on, '
          f'{args.rounds} rounds of {args.block_s:g} s blocks per state; CPU per period '
          f'(median) off: {statistics.median(off) * 1e6:.1f} us')
    for state in states[1:]:
        ratios = sorted(b / a for a, b in zip(off, per_period[state]))
        q = statistics.quantiles(ratios, n=4)
        print(f'  {state:8s} / off: median {statistics.median(ratios):.3f} (quartiles '
              f'{q[0]:.3f} .. {q[2]:.3f}), {statistics.median(per_period[state]) * 1e6:.1f} us '
              f'per period, of which the executor thread '
              f'{executor_cpu[state] / periods[state] * 1e6:.1f} us (off: '
              f'{executor_cpu["off"] / periods["off"] * 1e6:.1f} us), {periods[state]} periods')
    print('  the clients got ' + ', '.join(f'{state}: {count} messages'
                                           for state, count in received.items()))


if __name__ == '__main__':
    main()
