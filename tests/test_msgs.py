"""Messages: round trips, plain msgpack on the wire, refusal of bad bytes."""

import math

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dockhil import msgs
from dockhil.msgs.codec import DecodeError, decode, encode, schema

finite = st.floats(allow_nan=False, allow_infinity=False)
vec = st.builds(msgs.Vector3, finite, finite, finite)


def sample(cls):
    if cls is msgs.SatelliteState:
        return cls(
            header=msgs.Header(stamp=1.5, tick=3, seq=3, frame="com"),
            bodies=(
                msgs.BodyState(
                    "chaser", 750.0, msgs.Pose(msgs.Vector3(0.1, 0, 0)), msgs.Twist(msgs.Vector3(0.03, 0, 0))
                ),
            ),
        )
    if cls is msgs.BodyWrenches:
        return cls(header=msgs.Header(tick=1), wrenches=(msgs.Wrench(msgs.Vector3(1, 2, 3), msgs.Vector3(4, 5, 6)),))
    return cls(header=msgs.Header(stamp=0.25, tick=7, seq=7, frame="probe"))


@pytest.mark.parametrize("cls", list(msgs.TYPES.values()))
def test_round_trip_and_reference_msgpack(cls):
    m = sample(cls)
    b = encode(m)
    assert decode(b, cls) == m
    # The reference msgpack library reads the same bytes as plain maps...
    plain = msgpack.unpackb(b)
    assert plain["header"]["tick"] == m.header.tick
    # ...and bytes it writes decode as the typed message.
    assert decode(msgpack.packb(plain), cls) == m
    assert schema(cls)["$ref"].endswith(cls.__name__)


@given(vec, vec, st.integers(0, 2**62), finite.filter(lambda x: x >= 0))
def test_wrench_round_trip(f, t, tick, stamp):
    m = msgs.WrenchStamped(header=msgs.Header(stamp=stamp, tick=tick, seq=tick), wrench=msgs.Wrench(f, t))
    assert decode(encode(m), msgs.WrenchStamped) == m


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_refused_naming_the_field(bad):
    m = msgs.WrenchStamped(header=msgs.Header(), wrench=msgs.Wrench(force=msgs.Vector3(y=bad)))
    with pytest.raises(DecodeError) as e:
        decode(encode(m), msgs.WrenchStamped)
    assert "$.wrench.force.y" in str(e.value) and "NaN or Inf" in str(e.value)


def test_wrong_type_names_field():
    plain = msgpack.unpackb(encode(msgs.RobotCommand(header=msgs.Header())))
    plain["pose"]["position"]["x"] = "fast"
    with pytest.raises(DecodeError) as e:
        decode(msgpack.packb(plain), msgs.RobotCommand)
    assert "$.pose.position.x" in str(e.value) and "str" in str(e.value)


@settings(max_examples=400)
@given(st.binary(max_size=200))
def test_random_bytes_never_crash(data):
    for cls in msgs.TYPES.values():
        try:
            decode(data, cls)
        except DecodeError:
            pass


@settings(max_examples=200)
@given(
    st.recursive(
        st.none() | st.booleans() | st.floats() | st.integers(-(2**63), 2**64 - 1) | st.text(max_size=5),
        lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4),
        max_leaves=20,
    )
)
def test_random_msgpack_values_never_crash(value):
    data = msgpack.packb(value)
    for cls in msgs.TYPES.values():
        try:
            decode(data, cls)
        except DecodeError:
            pass


def test_wrong_message_type_and_unknown_fields_refused():
    state = encode(msgs.RobotState(header=msgs.Header()))
    with pytest.raises(DecodeError, match="Invalid value 'dockhil/RobotState' - at `\\$.type`"):
        decode(state, msgs.WrenchStamped)
    with pytest.raises(DecodeError, match="missing required field `header`"):
        decode(msgpack.packb({"wrench": {}}), msgs.WrenchStamped)
    with pytest.raises(DecodeError, match="unknown field `fx`"):
        decode(msgpack.packb({"header": {}, "wrench": {"force": {"fx": 1.0}}}), msgs.WrenchStamped)
    assert msgpack.unpackb(encode(msgs.EStop(header=msgs.Header())))["type"] == "dockhil/EStop"


@pytest.mark.parametrize("data", [b"\x81\xa4type\xa3\xff\xfe\xfd", b"\x81\xa3\xff\xfe\xfd\x01"])
def test_invalid_utf8_is_a_decode_error(data):
    for cls in msgs.TYPES.values():
        with pytest.raises(DecodeError, match="UTF-8|Expected|Invalid|unknown"):
            decode(data, cls)
