"""
The actuator's shape: geometry, its MarkerArray bytes and the node's marker topic.

The geometry comes from the Ritz basis (no ROS); the node's marker topic: display rate,
frames, q at the reference point, MCAP recording.
"""

from det_sim_ros.io.log import deserialize
from det_sim_ros.physics.geometry import ActuatorGeometry
from det_sim_ros.ros.markers import MARKER_TYPE, MarkerFrames
from det_sim_ros.scenes.scene import load_scene
from det_sim_ros.sim.simulator import Simulator
import numpy as np
import pytest

# the paper's one-term model: the fidelity is not the subject of these tests, and its
# numbers are the ones pinned here
PAPER = {'scene.fidelity': 'paper'}


def driven(scene, volts, steps=60):
    sim = Simulator(scene)
    sim.set_input(volts)
    for _ in range(steps):
        sim.step()
    return sim


def per_det(sim, base):
    out = sim.outputs()
    return [out[base]] if sim.model.n_inputs == 1 else [
        out[f'{base}[{d}]'] for d in sim.model.input_names]


@pytest.mark.parametrize('overrides', [
    {}, {'scene.beam': 'simply_supported'},
    {'scene.fidelity': 'consistent', 'scene.n_ritz': 3},
    {'scene.fidelity': 'exact', 'scene.n_ritz': 3, 'scene.beam': 'simply_supported'}])
def test_shape_matches_model_outputs(overrides):
    """
    Check that the drawn centre line comes from the model's basis and kinematics.

    The reference point's deflection is q and the moving end's height is l - y, for every
    fidelity.
    """
    scene = load_scene('default', overrides)
    sim = driven(scene, [3000.0])
    cell, = ActuatorGeometry(sim.model).cells(sim.x)
    q, y = per_det(sim, 'q')[0], per_det(sim, 'y')[0]
    assert cell.reference[0] == pytest.approx(q, rel=1e-13, abs=1e-18)
    assert abs(q) > 1e-3                       # buckled: a meaningful check
    assert cell.height == pytest.approx(scene.beam_length - y, rel=1e-12)
    np.testing.assert_allclose(cell.beam_b[:, 0], -cell.beam_a[:, 0])   # the mirror beam
    assert cell.beam_a[0, 2] == 0.0 and np.all(np.diff(cell.beam_a[:, 2]) > 0)
    # the markers' fast path (linear maps of q and w'^2) draws the same shape
    msg = deserialize(MARKER_TYPE, MarkerFrames(sim.model).frame(sim.x, sim.u, 0))
    beam_a, beam_b, det, ref = msg.markers
    np.testing.assert_allclose([[p.x, p.y, p.z] for p in beam_a.points], cell.beam_a,
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose([[p.x, p.y, p.z] for p in beam_b.points], cell.beam_b,
                               rtol=1e-12, atol=1e-15)
    assert ref.pose.position.x == pytest.approx(q, rel=1e-12)
    assert det.scale.z == pytest.approx(cell.height, rel=1e-12)
    assert det.scale.x == pytest.approx(cell.det_thickness, rel=1e-12)


def test_marker_bytes_decode_to_the_shape():
    """The patched CDR bytes are a valid MarkerArray with the shape, stamp and frames."""
    scene = load_scene('plate', PAPER)
    sim = driven(scene, [3000.0, 0.0], 120)
    frames = MarkerFrames(sim.model, frame_prefix='arm1/')
    msg = deserialize(MARKER_TYPE, frames.frame(sim.x, sim.u, 1_234_000_000))
    cells = frames.geometry.cells(sim.x)
    by_key = {(m.ns, m.id): m for m in msg.markers}
    assert set(by_key) == {(d, i) for d in ('left', 'right') for i in range(4)} | {('plate', 0)}
    for m in msg.markers:
        assert (m.header.stamp.sec, m.header.stamp.nanosec) == (1, 234_000_000)
    for name, cell, q in zip(('left', 'right'), cells, per_det(sim, 'q')):
        beam = by_key[name, 0]
        assert beam.header.frame_id == f'arm1/{name}'
        np.testing.assert_allclose([[p.x, p.y, p.z] for p in beam.points], cell.beam_a,
                                   rtol=1e-12, atol=1e-15)
        assert by_key[name, 3].pose.position.x == pytest.approx(q, rel=1e-13)
        assert by_key[name, 2].scale.z == pytest.approx(cell.height)
    plate = by_key['plate', 0]
    assert plate.header.frame_id == 'arm1/left'
    assert plate.pose.position.y == pytest.approx(0.5 * scene.structure['plate_width'])
    # the left DET at 3 kV rises more: the plate tilts towards the right (rotation about x < 0)
    assert cells[0].height > cells[1].height and plate.pose.orientation.x < 0
    # a second frame reuses the buffer: the bytes change only in the moving fields
    other = deserialize(MARKER_TYPE, frames.frame(np.zeros_like(sim.x), [0.0, 0.0], 0))
    assert other.markers[0].points[10].x == 0.0 and other.markers[0].header.stamp.sec == 0


def test_common_frame_lays_out_the_cells():
    scene = load_scene('array', {**PAPER, 'structure.copies': 3})
    sim = Simulator(scene)
    msg = deserialize(MARKER_TYPE, MarkerFrames(sim.model, frame_id='world').frame(
        sim.x, sim.u, 0))
    assert {m.header.frame_id for m in msg.markers} == {'world'}
    ys = sorted({m.pose.position.y for m in msg.markers if m.id == 0})
    assert len(ys) == 3 and ys[0] == 0.0 and ys[1] > 0.0


@pytest.mark.ros
def test_node_publishes_markers_at_the_display_rate(harness, tmp_path):
    """
    Check that the node publishes 30 frames per simulated second, all logged.

    30 frames per simulated second, stamped on the sample grid, all in the MCAP log; the
    reference point's deflection equals the q published for the same sample. (What reaches a
    viewer in free run is capped in wall time: test_viewers_get_frames_at_most_...)
    """
    from visualization_msgs.msg import MarkerArray
    log = tmp_path / 'run.mcap'
    h = harness(start_paused=True, **{'log.path': str(log)})
    frames = []
    h.subs.append(h.test.create_subscription(MarkerArray, 'markers', frames.append, 100))
    h.spin_until(lambda: h.subs[-1].get_publisher_count() > 0, 'marker discovery')
    h.command([3000.0])
    assert h.call('pause', data=False).success
    h.spin_until_sim_time(0.3)
    h.spin_until(lambda: len(frames) >= 3, 'marker frames of the snap-through')
    assert h.call('pause', data=True).success
    every = h.node.markers.every
    assert every == round(1000 / 30)

    def stamp_k(frame):
        stamp = frame.markers[0].header.stamp
        t_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        k = round(t_ns / 1e6)
        assert k % every == 0 and t_ns == k * 1_000_000
        return k, t_ns

    # the node equals the offline model sample for sample (test_sim_node), so the published q
    # at every frame's stamp is the offline q at that sample
    last = max(stamp_k(frame)[0] for frame in frames)
    sim = Simulator(h.node.scene)
    sim.set_input([3000.0])
    q = [sim.outputs()['q']] + [sim.step()[sim.output_names.index('q')] for _ in range(last)]
    for frame in frames:
        k, t_ns = stamp_k(frame)
        ref = next(m for m in frame.markers if m.id == 3)
        assert ref.header.frame_id == 'det0'
        assert ref.pose.position.x == pytest.approx(q[k], rel=1e-12, abs=1e-18)
        if t_ns in h.samples['deflection']:     # and what the node published for it
            assert ref.pose.position.x == pytest.approx(h.samples['deflection'][t_ns][0],
                                                        rel=1e-12, abs=1e-18)
    h.close()
    from det_sim_ros.io.log import LogReader
    logged = [m for m in LogReader(str(log)).messages() if m.topic == '/markers']
    assert logged and logged[0].type_name == MARKER_TYPE
    # the snap-through moves the beam: every frame of the display grid is in the log
    assert [m.log_time for m in logged if m.log_time <= 300_000_000] == [
        k * 1_000_000 for k in range(0, 301, every)]


def test_viewers_get_frames_at_most_twice_per_display_period_of_wall_time():
    """
    Check that viewers get frames at most twice per display period of wall time.

    Free run at ~6.6x real time (a display-grid sample every 5 ms of wall time): the log
    gets every frame, viewers one per 16.7 ms of wall time (half the 30 Hz display period);
    at real-time pace viewers get every frame; a frame held back while the beam moved is sent
    once it settles, so a viewer ends with the last shape.
    """
    import types
    from det_sim_ros.ros.markers import NodeMarkers
    sent, logged, now = [], [], [0.0]
    publisher = types.SimpleNamespace(publish=sent.append,
                                      get_subscription_count=lambda: 1)
    node = types.SimpleNamespace(get_namespace=lambda: '/',
                                 create_publisher=lambda *args: publisher)
    recorder = types.SimpleNamespace(record=lambda topic, data, t, type_name: logged.append(t))
    sim = Simulator(load_scene('default', PAPER))
    markers = NodeMarkers(node, sim.model, 30.0, '', 10, clock=lambda: now[0])
    sim.set_input([3000.0])

    def run(periods, wall_per_period):
        for _ in range(periods):
            sim.step()
            k = sim.k
            frame = markers.frame_for(k, sim.x, sim.u, k * 1_000_000, recorder)
            if frame is not None:
                markers.publish(frame)
            now[0] += wall_per_period

    run(330, 0.005 / 33)                       # 10 grid samples, 5 ms of wall time apart
    assert logged == [k * 1_000_000 for k in range(33, 331, 33)]   # (the snap: all moved)
    assert len(sent) == 3 and markers.held_back == 7    # at 5, 25 and 45 ms of wall time
    run(330, 0.001)                            # real-time pace: nothing is held back
    assert markers.held_back == 7 and len(sent) - 3 >= len(logged) - 10 > 0
    sim.set_input([0.0])
    run(3000, 0.005 / 33)    # released at free-run pace: it snaps back and settles
    assert markers.held_back > 7
    ref = next(m for m in deserialize(MARKER_TYPE, sent[-1]).markers if m.id == 3)
    assert ref.pose.position.x == pytest.approx(sim.outputs()['q'], abs=1e-6)   # not stale


def test_frames_that_show_nothing_new_are_not_sent():
    """
    Check that frame_if_moved sends a frame only when something changed.

    frame_if_moved: a frame when a coordinate moved by more than MOVE_TOLERANCE, the
    voltage changed, or KEEPALIVE_S passed; otherwise None. What is sent is frame()'s bytes.
    """
    from det_sim_ros.ros.markers import KEEPALIVE_NS, MarkerFrames, MOVE_TOLERANCE
    sim = Simulator(load_scene('default', PAPER))
    frames = MarkerFrames(sim.model)
    x, u = sim.x.copy(), sim.u.copy()
    first = frames.frame_if_moved(x, u, 0)
    assert first == frames.frame(x, u, 0)
    assert frames.frame_if_moved(x, u, 1_000_000) is None            # at rest: nothing new
    assert frames.frame_if_moved(x, u, KEEPALIVE_NS - 1) is None and frames.skipped == 2
    assert frames.frame_if_moved(x, u, KEEPALIVE_NS) is not None     # the keep-alive
    assert frames.frame_if_moved(x, u + 1.0, KEEPALIVE_NS + 1) is not None   # a new voltage
    moved = x.copy()
    q0 = frames.values(x)
    for scale in (1e-12, 1e-3):    # a tiny and a visible change of q (the first coordinate)
        moved[0] = x[0] * (1.0 + scale)
        shift = float(np.max(np.abs(frames.values(moved) - q0)))
        sent = frames.frame_if_moved(moved, u + 1.0, KEEPALIVE_NS + 2)
        assert (sent is not None) == (shift > MOVE_TOLERANCE)
        assert sent is None or sent == frames.frame(moved, u + 1.0, KEEPALIVE_NS + 2)


@pytest.mark.parametrize('name, overrides, volts', [
    ('default', PAPER, [2500.0]),
    ('default', {'scene.fidelity': 'consistent', 'scene.n_ritz': 1}, [2500.0]),
    ('plate', PAPER, [3000.0, 0.0]),
    ('array', {**PAPER, 'structure.copies': 3}, [2500.0, 1000.0, 0.0])])
def test_stacked_cells_give_the_general_paths_frame(name, overrides, volts):
    """
    Check that the stacked and compiled frame paths give the general path's frame.

    One-coordinate cells take the stacked polynomial map (all cells at once), and without a
    plate the compiled FrameMap (frames.c) builds the node's frames from it. The stacked map
    draws what the general basis-and-kinematics path draws; the compiled frames are the
    numpy frames' bytes exactly; all three agree on whether a frame moved enough to send.
    """
    from det_sim_ros.ros.markers import MOVE_TOLERANCE
    sim = driven(load_scene(name, overrides=overrides), volts, 40)

    def paths():
        return (MarkerFrames(sim.model), MarkerFrames(sim.model, paths=('stacked',)),
                MarkerFrames(sim.model, paths=('general',)))

    compiled, stacked, general = paths()
    assert (stacked.path, general.path) == ('stacked', 'general')
    assert compiled.path == ('stacked' if name == 'plate' else 'compiled')
    np.testing.assert_allclose(stacked.values(sim.x), general.values(sim.x),
                               rtol=1e-12, atol=1e-16)
    drawn = [[(p.x, p.y, p.z) for m in deserialize(MARKER_TYPE, f.frame(sim.x, sim.u, 7)).markers
              for p in m.points] for f in (stacked, general)]
    np.testing.assert_allclose(drawn[0], drawn[1], rtol=1e-12, atol=1e-16)
    sent = compiled.frame_if_moved(sim.x, sim.u, 5_000_000_007)
    assert sent == stacked.frame(sim.x, sim.u, 5_000_000_007)
    for shift in (0.0, 1e-13, 1e-9, 1e-6):   # still, below, near and above the tolerance
        moved = sim.x.copy()
        moved[[cell.start for cell in stacked.geometry.slices]] += shift   # each cell's q
        frames = paths()
        for f in frames:
            f.frame_if_moved(sim.x, sim.u, 0)
        sent = [f.frame_if_moved(moved, sim.u, 1) for f in frames]
        shown = np.max(np.abs(general.values(moved) - general.values(sim.x)))
        assert [s is not None for s in sent] == [shown > MOVE_TOLERANCE] * 3
        assert sent[0] == sent[1]


def test_compiled_frames_refuse_wrong_buffers():
    """FrameMap.update checks what it writes into: the frame's size and the state's length."""
    sim = Simulator(load_scene('default', PAPER))
    frames = MarkerFrames(sim.model, paths=('compiled',))
    update = frames.frame_map.update
    with pytest.raises(ValueError, match='frame: expected'):
        update(sim.x, bytearray(10), True, 0)
    with pytest.raises(ValueError, match='shorter than'):
        update(sim.x[:0].copy(), bytearray(frames.size), True, 0)
    with pytest.raises(BufferError):
        update(sim.x, bytes(frames.size), True, 0)      # read-only bytes
    assert update(sim.x, bytearray(frames.size), True, 0) is True


def test_frame_paths_refuse_what_the_model_cannot_take():
    """A plate has no compiled or stacked path; asking for only those is a clear error."""
    sim = Simulator(load_scene('plate', PAPER))
    with pytest.raises(ValueError, match='none of them'):
        MarkerFrames(sim.model, paths=('compiled',))
    with pytest.raises(ValueError, match='expected some of'):
        MarkerFrames(sim.model, paths=('fast',))


@pytest.mark.ros
def test_no_frames_without_a_viewer_or_a_log(harness):
    """
    Check that the node builds no frames without a marker subscriber or a log.

    The work would be lost; frames start when a viewer subscribes.
    """
    from visualization_msgs.msg import MarkerArray
    h = harness(start_paused=True, **{'log.enabled': False})
    markers = h.node.markers
    h.command([3000.0])
    assert h.call('pause', data=False).success
    h.spin_until_sim_time(0.2)
    assert markers.published == 0 and markers.frames.skipped == 0
    frames = []
    h.subs.append(h.test.create_subscription(MarkerArray, 'markers', frames.append, 100))
    h.spin_until(lambda: len(frames) >= 2, 'marker frames once a viewer subscribed')
    assert markers.published >= 2
    h.close()


@pytest.mark.ros
def test_markers_off(harness):
    h = harness(**{'markers.rate_hz': 0.0})
    assert h.node.markers is None
    names = {n for n, _ in h.node.get_publisher_names_and_types_by_node('sim_node', '/')}
    assert '/markers' not in names


def test_foxglove_layout_uses_the_nodes_topics():
    """
    Check that config/foxglove_layout.json uses the node's topics and fields.

    A 3D panel on /markers following det0's frame, and plots of voltage, Delta-y, q, charge and
    current on topics and fields the node publishes.
    """
    import json
    import os
    import re
    from det_sim_ros.ros.shell import OUTPUT_TOPICS
    path = os.path.join(os.path.dirname(__file__), '..', 'config', 'foxglove_layout.json')
    with open(path, encoding='utf-8') as stream:
        layout = json.load(stream)
    panels = layout['configById']
    three_d = [c for k, c in panels.items() if k.startswith('3D!')]
    assert len(three_d) == 1 and three_d[0]['topics']['/markers']['visible']
    assert three_d[0]['followTf'] == 'det0'
    fields = {'voltage_command': {'data'}, **{t: {'position', 'velocity'} for t in OUTPUT_TOPICS}}
    plotted = set()
    for key, config in panels.items():
        if key.startswith('Plot!'):
            for p in config['paths']:
                topic, field = re.fullmatch(r'/(\w+)\.(\w+)\[\d+\]', p['value']).groups()
                assert field in fields[topic], p['value']
                plotted.add(topic)
    assert plotted == {'voltage_command', 'displacement', 'deflection', 'charge', 'current'}

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node['first']) + leaves(
            node['second'])
    assert sorted(leaves(layout['layout'])) == sorted(panels)
