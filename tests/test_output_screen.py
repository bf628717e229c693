"""A node sends exactly what its readers accept, and a composed run, which screens the numbers of
a message with a function generated from its type, refuses a number out of bounds with the same line."""

import math

import msgspec
import pytest

from dockhil import msgs
from dockhil.errors import DockhilError
from dockhil.msgs import (
    BodyState,
    BodyWrenches,
    Header,
    Pose,
    Quaternion,
    RobotState,
    SatelliteState,
    Twist,
    Vector3,
    Wrench,
    WrenchStamped,
)
from dockhil.runtime.screen import check_message, checked_payload


def reader_accepts(msg) -> bool:
    """What a reader does, written with msgspec alone: decode the bytes as the message's type."""
    try:
        msgspec.msgpack.decode(msgspec.msgpack.encode(msg), type=type(msg))
    except msgspec.ValidationError:
        return False
    return True


CASES = [
    *(msgs.TYPES[name](header=Header()) for name in msgs.TYPES),
    WrenchStamped(header=Header(stamp=1.5, tick=3, seq=3), wrench=Wrench(force=Vector3(x=-2.0))),
    WrenchStamped(header=Header(), wrench=Wrench(force=Vector3(x=1e308, y=1e308))),  # the sum overflows: fine
    WrenchStamped(header=Header(), wrench=Wrench(force=Vector3(x=1))),  # an int where a float goes: accepted
    WrenchStamped(header=Header(stamp=math.inf)),
    WrenchStamped(header=Header(), wrench=Wrench(torque=Vector3(z=-math.inf))),
    WrenchStamped(header=Header(), wrench=Wrench(force=Vector3(x="1.0"))),  # a string in a float field
    WrenchStamped(header=Header(), wrench=Wrench(force=Vector3(x=True))),  # a bool in a float field
    WrenchStamped(header=Header(frame=7)),  # an int in a string field
    WrenchStamped(header=Header(tick=1.0)),  # a float in an int field
    RobotState(header=Header(), pose=Pose(position=Quaternion())),  # a struct of another type
    SatelliteState(header=Header(), bodies=[BodyState(mass=-1.0)]),
    SatelliteState(header=Header(), bodies=(BodyState(),)),  # a tuple where a list goes: accepted
    SatelliteState(header=Header(), bodies=[BodyState(twist=Twist(angular=Vector3(y=math.nan)))]),
    BodyWrenches(header=Header(), wrenches=[Wrench(), Vector3()]),
]


@pytest.mark.parametrize("msg", CASES, ids=range(len(CASES)))
def test_a_node_sends_exactly_what_a_reader_accepts(msg):
    if reader_accepts(msg):
        assert checked_payload("n", "p", "/t", 4, msg) == msgspec.msgpack.encode(msg)
        return
    with pytest.raises(DockhilError) as sent:
        checked_payload("n", "p", "/t", 4, msg)
    assert str(sent.value).startswith("node 'n' produced an invalid message at tick 4 on output 'p' (/t): ")


OUT_OF_BOUNDS = [
    WrenchStamped(header=Header(stamp=math.inf)),
    WrenchStamped(header=Header(stamp=-1.0)),
    WrenchStamped(header=Header(seq=-1)),
    SatelliteState(header=Header(), bodies=[BodyState(), BodyState(twist=Twist(angular=Vector3(y=math.nan)))]),
    SatelliteState(header=Header(), bodies=[BodyState(mass=-1.0)]),
]


@pytest.mark.parametrize("msg", OUT_OF_BOUNDS, ids=range(len(OUT_OF_BOUNDS)))
def test_a_composed_run_refuses_a_number_out_of_bounds_with_the_same_line(msg):
    assert not reader_accepts(msg)
    with pytest.raises(DockhilError) as sent:
        checked_payload("n", "p", "/t", 4, msg)
    with pytest.raises(DockhilError) as composed:
        check_message("n", "p", "/t", 4, msg)
    assert str(composed.value) == str(sent.value)


@pytest.mark.parametrize("msg", CASES, ids=range(len(CASES)))
def test_a_composed_run_refuses_exactly_what_a_reader_refuses_with_the_same_line(msg):
    # The screen judges the values' types too (a bool or a str in a float field, an int in a str
    # field, a struct of another type): a composed run and node processes agree on every message.
    if reader_accepts(msg):
        check_message("n", "p", "/t", 4, msg)
        return
    with pytest.raises(DockhilError) as sent:
        checked_payload("n", "p", "/t", 4, msg)
    with pytest.raises(DockhilError) as composed:
        check_message("n", "p", "/t", 4, msg)
    assert str(composed.value) == str(sent.value)


def test_the_screen_passes_good_messages_without_the_full_check():
    # A screen that said False for everything would be right and slow: the messages the nodes
    # build pass it as they are.
    from dockhil.runtime.screen import bounds_check

    good = [
        WrenchStamped(header=Header(stamp=1.5, tick=3, seq=3, frame="f"), wrench=Wrench(force=Vector3(1.0, 2.0, 3.0))),
        SatelliteState(header=Header(), bodies=(BodyState("chaser", 750.0), BodyState("target", 1e6)), in_contact=True),
        BodyWrenches(header=Header(), wrenches=(Wrench(), Wrench(Vector3(1.0, 0.0, 0.0), Vector3()))),
    ]
    assert all(bounds_check(type(m))(m) for m in good)


@pytest.mark.parametrize("scene", ["hil.yaml", "hil6.yaml"])
def test_the_shipped_scenes_messages_pass_the_screen_as_they_are(scene, monkeypatch):
    # Each message the screen turns down costs an encode and a decode: the built-in nodes build
    # plain floats, strs and ints, so none of theirs is.
    import dockhil.runtime.composed as composed
    from dockhil.scene import graph as graphmod
    from dockhil.scene import launchfile
    from tests.conftest import ROOT

    full = []
    monkeypatch.setattr(composed, "checked_payload", lambda *a: full.append(a[:3]))
    g = composed.ComposedGraph(graphmod.build(launchfile.load(ROOT / "launch" / scene)), log=lambda n, m: None)
    g.setup()
    g.run(600)  # into the contact
    g.close()
    assert full == []


def _mutants(seed: int, n: int):
    """Messages of every type with one value swapped for something a reader may refuse."""
    import random

    rng = random.Random(seed)
    odd = [math.nan, math.inf, -math.inf, True, False, 1, -1, "x", None, 1e308, -0.0, (), [], Vector3()]

    def paths(obj, prefix=()):
        for name in obj.__struct_fields__:
            v = getattr(obj, name)
            yield prefix + (name,)
            if isinstance(v, msgspec.Struct):
                yield from paths(v, prefix + (name,))

    def swapped(obj, path, value):
        if len(path) == 1:
            return msgspec.structs.replace(obj, **{path[0]: value})
        return msgspec.structs.replace(obj, **{path[0]: swapped(getattr(obj, path[0]), path[1:], value)})

    bases = [msgs.TYPES[name](header=Header(stamp=1.0, tick=2, seq=2, frame="f")) for name in sorted(msgs.TYPES)]
    bases.append(SatelliteState(header=Header(), bodies=(BodyState("chaser", 750.0), BodyState("target", 1e6))))
    for _ in range(n):
        base = rng.choice(bases)
        path = rng.choice(list(paths(base)))
        yield swapped(base, path, rng.choice(odd))


def test_the_compiled_screen_judges_as_its_python_twin():
    from dockhil.compiled import twin
    from dockhil.runtime import screen

    if twin("dockhil.runtime._screen") is None:
        pytest.skip("dockhil.runtime._screen is not built here")
    passed = 0
    for msg in [*CASES, *_mutants(3, 3000)]:
        compiled, python = screen.bounds_check(type(msg))(msg), screen.python_screen(type(msg))(msg)
        # Either may only pass what a reader accepts; the compiled one passes all the twin passes
        # (and more: a sum of finite values that overflows, which the twin sends to the full check).
        assert compiled <= reader_accepts(msg) and python <= compiled, msg
        passed += compiled
    assert passed > 200  # the good ones among them are judged without the full check
