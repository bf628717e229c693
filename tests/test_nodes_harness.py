"""dockhil.testing.NodeHarness: the schedule a launched graph gives a node, in one process;
and the bag_source node, stepped with it."""

from __future__ import annotations

import pytest

from dockhil import msgs
from dockhil.bags.writer import BagWriter
from dockhil.errors import DockhilError, ParamError
from dockhil.msgs import RobotCommand, Vector3, Wrench, WrenchStamped
from dockhil.msgs.codec import encode
from dockhil.node import Input, Node, Output, Param
from dockhil.testing import NodeHarness, robot_command, wrench


class Probe(Node):
    """Echoes what each input read at this tick: the force, or -1 for None."""

    inputs = {
        "now": Input(WrenchStamped, "/now"),
        "late": Input(WrenchStamped, "/late", feedthrough=False),
        "delayed": Input(WrenchStamped, "/delayed", delay=0.003),
    }
    outputs = {"seen": Output(WrenchStamped, "/seen")}
    params = {"closed": Param(bool, False, help="set by close()")}

    def step(self, tick, inputs):
        def f(port):
            return -1.0 if inputs[port] is None else inputs[port].wrench.force.x

        return {"seen": WrenchStamped(header=tick.header(), wrench=Wrench(Vector3(f("now"), f("late"), f("delayed"))))}

    def close(self):
        self.closed = True


def seen(out):
    v = out["seen"].wrench.force
    return v.x, v.y, v.z


def feed(k):
    return {port: wrench(fx=float(k)) for port in ("now", "late", "delayed")}


def test_feedthrough_reads_this_tick_a_state_input_the_last_and_a_delayed_input_round_delay_over_dt_ago():
    with NodeHarness(Probe, dt=0.001) as h:
        outs = h.run(8, inputs=feed)
    assert [seen(o) for o in outs] == [(k, k - 1 if k >= 1 else -1, k - 3 if k >= 3 else -1) for k in range(8)]


def test_a_tick_without_a_message_reads_none_in_sim_time_and_the_latest_in_wall_time():
    given = {0: feed(0), 1: {}, 2: {}, 3: feed(3), 4: {}, 5: {}, 6: {}}
    with NodeHarness(Probe) as h:
        sim = [seen(h.step(given[k])) for k in range(7)]
    assert [s[0] for s in sim] == [0, -1, -1, 3, -1, -1, -1]
    assert [s[1] for s in sim] == [-1, 0, -1, -1, 3, -1, -1]
    with NodeHarness(Probe, sim_time=False) as h:
        wall = [seen(h.step(given[k])) for k in range(7)]
    assert [s[0] for s in wall] == [0, 0, 0, 3, 3, 3, 3]
    assert [s[1] for s in wall] == [-1, 0, 0, 0, 3, 3, 3]


def test_inputs_are_stamped_with_their_tick_and_time_is_the_tests():
    class Stamps(Node):
        inputs = {"w": Input(WrenchStamped, "/w")}
        outputs = {"stamp": Output(WrenchStamped, "/s")}

        def step(self, tick, inputs):
            h = inputs["w"].header
            return {"stamp": WrenchStamped(header=tick.header(), wrench=Wrench(Vector3(h.tick, h.stamp, tick.t)))}

    with NodeHarness(Stamps, dt=0.01) as h:
        h.step({"w": wrench(frame="probe")})
        v = h.step({"w": wrench()})["stamp"].wrench.force
        assert (v.x, v.y, v.z) == (1.0, 0.01, 0.01)
        assert h.step({"w": wrench()}, t=7.5)["stamp"].header.stamp == 7.5


def test_bad_inputs_and_outputs_are_refused_with_one_line():
    class Liar(Node):
        outputs = {"x": Output(WrenchStamped, "/x")}
        params = {"how": Param(str, "type")}

        def step(self, tick, inputs):
            if self.p.how == "type" or (self.p.how == "type later" and tick.index > 0):
                return {"x": robot_command()}
            if self.p.how == "type later":
                return {"x": WrenchStamped(header=tick.header())}
            if self.p.how == "port":
                return {"y": wrench()}
            return {"x": WrenchStamped(header=msgs.Header(tick=tick.index + 1))}

    with NodeHarness(Liar, how="type") as h:
        with pytest.raises(DockhilError, match=r"output 'x' at tick 0: expected WrenchStamped, got RobotCommand"):
            h.step()
    with NodeHarness(Liar, how="port") as h:
        with pytest.raises(DockhilError, match=r"returned undeclared output 'y' at tick 0"):
            h.step()
    with NodeHarness(Liar, how="type later", sim_time=False) as h:  # wall time: every tick is checked too
        h.step()
        with pytest.raises(DockhilError, match=r"output 'x' at tick 1: expected WrenchStamped, got RobotCommand"):
            h.step()
    with NodeHarness(Liar, how="tick") as h:
        with pytest.raises(DockhilError, match=r"carries header.tick 1; build headers with tick.header\(\)"):
            h.step()
    with NodeHarness(Probe) as h:
        with pytest.raises(DockhilError, match=r"node 'Probe' has no input 'nope'; inputs: now, late, delayed"):
            h.step({"nope": wrench()})
        with pytest.raises(DockhilError, match=r"node 'Probe' input 'now' takes WrenchStamped, got RobotCommand"):
            h.step({"now": robot_command()})
    with pytest.raises(ParamError, match=r"unknown parameter 'gain'"):
        NodeHarness(Probe, gain=2.0)
    with pytest.raises(DockhilError, match=r"call setup\(\) before step\(\)"):
        NodeHarness(Probe).step()


def test_close_runs_the_nodes_close_and_names_resolve_like_a_launch_file():
    h = NodeHarness(Probe).setup()
    h.close()
    assert h.node.closed
    assert NodeHarness("tests.test_nodes_harness:Probe").cls is Probe
    assert NodeHarness("delay_injector", delay=0.0).name == "delay_injector"


# -- bag_source ------------------------------------------------------------------------------


@pytest.fixture
def bag(tmp_path):
    """A recorded run at 1 kHz: /ft/wrench at ticks 0..9 but for tick 4; /robot/command at even ticks."""
    path = tmp_path / "run.mcap"
    with BagWriter(path) as b:
        b.add_topic("/ft/wrench", msgs.type_name(WrenchStamped))
        b.add_topic("/robot/command", msgs.type_name(RobotCommand))
        for k in range(10):
            ns = k * 1_000_000
            if k != 4:
                msg = WrenchStamped(
                    header=msgs.Header(stamp=k * 0.001, tick=k, seq=k, frame="probe"), wrench=Wrench(Vector3(x=0.5 * k))
                )
                b.write("/ft/wrench", ns, ns, encode(msg))
            if k % 2 == 0:
                cmd = RobotCommand(header=msgs.Header(stamp=k * 0.001, tick=k, seq=k), pose=msgs.Pose(Vector3(x=k)))
                b.write("/robot/command", ns, ns, encode(cmd))
    return str(path)


def test_bag_source_replays_each_tick_as_recorded_and_says_where_the_bag_ends(bag):
    with NodeHarness("bag_source", path=bag) as h:
        assert set(h.output_ports) == {"/ft/wrench", "/robot/command"}
        outs = h.run(10)
        with pytest.raises(DockhilError, match=r"has no tick 10: it ends at tick 9; shorten the run"):
            h.step()
    for k, out in enumerate(outs):
        assert ("/ft/wrench" in out) == (k != 4)  # an empty recorded tick stays empty
        assert ("/robot/command" in out) == (k % 2 == 0)
        if k != 4:
            w = out["/ft/wrench"]
            assert w.wrench.force.x == 0.5 * k and w.header.tick == k and w.header.frame == "probe"


def test_bag_source_start_skips_ticks_and_renumbers_and_topics_select(bag):
    with NodeHarness("bag_source", path=bag, topics=["/ft/wrench"], start=0.005) as h:
        assert set(h.output_ports) == {"/ft/wrench"}
        outs = h.run(5)
    assert [o["/ft/wrench"].wrench.force.x for o in outs] == [2.5, 3.0, 3.5, 4.0, 4.5]
    assert [o["/ft/wrench"].header.tick for o in outs] == [0, 1, 2, 3, 4]


def test_bag_source_in_wall_time_emits_what_is_due_by_log_time(bag):
    with NodeHarness("bag_source", path=bag, topics=["/robot/command"], sim_time=False) as h:
        xs = [h.step(t=t).get("/robot/command") for t in (0.0, 0.0025, 0.0025, 0.0081)]
    assert [None if m is None else m.pose.position.x for m in xs] == [0.0, 2.0, None, 8.0]


def test_bag_source_refuses_a_topic_not_in_the_bag(bag):
    with pytest.raises(DockhilError, match=r"no messages on /estop; topics in the bag: /ft/wrench, /robot/command"):
        NodeHarness("bag_source", path=bag, topics=["/estop"])


# -- the node-writing guide's own example ------------------------------------------------------


def test_the_node_writing_guides_example_node_scene_and_test_work(tmp_path, monkeypatch):
    import re
    import sys

    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build
    from tests.conftest import ROOT

    text = (ROOT / "docs" / "writing-a-node.md").read_text()
    node_py, scene_yaml, test_py = (body for _, body in re.findall(r"```(python|yaml)\n(.*?)```", text, re.S))
    (tmp_path / "spring_node.py").write_text(node_py)
    (tmp_path / "scene.yaml").write_text(scene_yaml)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "spring_node", raising=False)
    space: dict = {}
    exec(compile(test_py, "writing-a-node.md", "exec"), space)
    space["test_spring_pulls_back_to_the_set_point"]()
    # The scene builds, and the spring pulls the chaser from x1 = 0.01 towards 0, its set point.
    g = ComposedGraph(build(launchfile.load(str(tmp_path / "scene.yaml"))), log=lambda name, line: None)
    xs = []
    g.taps.append(lambda topic, msg: xs.append(msg.bodies[0].pose.position.x) if topic == "/satellite/state" else None)
    g.setup()
    g.run(300)
    g.close()
    assert xs[0] == 0.01 and 0.0 < xs[-1] < 0.01 and all(b <= a for a, b in zip(xs, xs[1:]))
