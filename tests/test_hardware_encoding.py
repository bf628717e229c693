"""F/T CAN frames and robot Modbus registers, encoded and decoded both ways."""

from __future__ import annotations

import struct

import pytest

from dockhil.devices.can_ft import frames as ff
from dockhil.devices.modbus_robot import registers as mm

# -- F/T CAN frames -------------------------------------------------------------


def test_sample_round_trip_with_default_scaling():
    frames = ff.encode_sample((12.34, -0.5, 300.0), (0.25, -1.5, 0.001), seq=7)
    assert [fid for fid, _ in frames] == [0x1A0, 0x1A1]
    assert all(len(data) == 8 for _, data in frames)
    halves = [ff.decode_frame(fid, data) for fid, data in frames]
    assert halves[0].kind == ff.FORCE and halves[1].kind == ff.TORQUE
    assert halves[0].counts == (1234, -50, 30000)
    assert halves[1].counts == (250, -1500, 1)
    assert halves[0].values == pytest.approx((12.34, -0.5, 300.0))
    assert halves[1].values == pytest.approx((0.25, -1.5, 0.001))
    assert {h.seq for h in halves} == {7} and {h.status for h in halves} == {0}


def test_frame_bytes_are_the_documented_layout():
    frames = ff.encode_sample((1.0, -1.0, 0.0), (0.0, 0.0, 0.002), seq=300, base_id=0x300, status=ff.STATUS_FAULT)
    (force_id, force), (torque_id, torque) = frames
    assert (force_id, torque_id) == (0x300, 0x301)
    # Fx = 100 counts, Fy = -100 counts, little-endian int16; status byte; sequence wraps at 256.
    assert force == bytes([100, 0, 0x9C, 0xFF, 0, 0, ff.STATUS_FAULT, 300 % 256])
    assert torque == struct.pack("<hhhBB", 0, 0, 2, ff.STATUS_FAULT, 44)


def test_scaling_is_a_parameter_both_ways():
    scaling = ff.FtScaling(force_resolution=1 / 64, torque_resolution=1 / 2048)
    frames = ff.encode_sample((1.0, 2.0, -3.0), (0.5, 0.0, 0.0), seq=0, scaling=scaling)
    force = ff.decode_frame(*frames[0], scaling=scaling)
    torque = ff.decode_frame(*frames[1], scaling=scaling)
    assert force.counts == (64, 128, -192) and force.values == (1.0, 2.0, -3.0)
    assert torque.counts == (1024, 0, 0) and torque.values == (0.5, 0.0, 0.0)
    with pytest.raises(ValueError, match="force_resolution"):
        ff.FtScaling(force_resolution=0.0)


def test_saturation_clips_and_flags_overrange_on_both_frames():
    frames = ff.encode_sample((1000.0, 0.0, 0.0), (0.0, 0.0, 0.0), seq=1)
    halves = [ff.decode_frame(fid, data) for fid, data in frames]
    assert halves[0].counts[0] == 32767
    assert all(h.status & ff.STATUS_OVERRANGE for h in halves)
    assert ff.describe_status(halves[0].status) == "overrange"


def test_encode_refuses_non_finite_values_and_bad_ids():
    with pytest.raises(ValueError, match="finite"):
        ff.encode_sample((float("nan"), 0.0, 0.0), (0.0, 0.0, 0.0), seq=0)
    with pytest.raises(ValueError, match="base ID"):
        ff.encode_sample((0.0,) * 3, (0.0,) * 3, seq=0, base_id=0x7FF)


def test_frames_of_other_devices_are_not_ours():
    data = bytes(8)
    assert ff.decode_frame(0x123, data) is None
    assert ff.decode_frame(0x1A0, data, is_extended_id=True) is None


@pytest.mark.parametrize(
    "data, remote, message",
    [
        (bytes(5), False, r"F/T force frame 0x1a0: 5 data bytes, expected 8"),
        (bytes(9), False, r"9 data bytes"),
        (b"", True, r"remote frame"),
    ],
)
def test_malformed_frames_on_our_ids_raise_a_clear_error(data, remote, message):
    with pytest.raises(ff.FrameError, match=message):
        ff.decode_frame(0x1A0, data, is_remote_frame=remote)


def test_assembler_pairs_by_sequence_and_counts_orphans():
    asm = ff.SampleAssembler()
    f1, t1 = (ff.decode_frame(*fr) for fr in ff.encode_sample((1.0, 0, 0), (0.1, 0, 0), seq=1))
    f2, t2 = (ff.decode_frame(*fr) for fr in ff.encode_sample((2.0, 0, 0), (0.2, 0, 0), seq=2))
    assert asm.add(f1) is None
    sample = asm.add(t1)
    assert sample == ff.FtSample((1.0, 0.0, 0.0), (0.1, 0.0, 0.0), 0, 1)
    assert asm.add(t2) is None  # torque without its force frame
    assert asm.add(f1) is None
    assert asm.add(f2) is None  # replaces f1 before its torque arrived
    assert asm.add(t2).force == (2.0, 0.0, 0.0)
    assert asm.orphans == 2


# -- Robot Modbus registers ----------------------------------------------------

POSE = (0.012345, -1.5, 2.0, 0.0, 0.0, 0.707106781, 0.707106781, 0.03, -0.001, 0.0, 0.0, 0.0, 0.1)


def test_pose_block_round_trip_exact_in_whole_counts():
    regs = mm.encode_block(POSE)
    assert len(regs) == mm.BLOCK_REGISTERS == 26
    assert all(0 <= r <= 0xFFFF for r in regs)
    assert mm.decode_block(regs) == POSE


def test_int32_is_big_endian_high_word_first():
    assert mm.int32_to_registers(0x12345678) == (0x1234, 0x5678)
    assert mm.int32_to_registers(-1) == (0xFFFF, 0xFFFF)
    assert mm.registers_to_int32(0xFFFF, 0xFFFE) == -2
    # position.x = 0.012345 m = 12345 counts of 1 um
    assert mm.encode_block(POSE)[:2] == [0, 12345]


def test_host_write_round_trip():
    regs = mm.encode_write(mm.CONTROL_ENABLE, 0x1_0005, POSE)  # the heartbeat is a wrapping u16
    assert len(regs) == mm.HR_COUNT == 28
    host = mm.decode_holding(regs)
    assert host == mm.HostWrite(mm.CONTROL_ENABLE, 5, POSE)
    assert mm.encode_write(mm.CONTROL_ENABLE | mm.CONTROL_HOLD, 9) == [3, 9]


def test_controller_inputs_round_trip():
    regs = mm.encode_inputs(mm.STATUS_ENABLED | mm.STATUS_FOLLOWING, 41, 65535, POSE)
    assert regs[:2] == [0x4448, 1] and len(regs) == mm.IR_COUNT == 31
    reading = mm.decode_inputs(regs)
    assert reading == mm.ControllerReading(mm.STATUS_ENABLED | mm.STATUS_FOLLOWING, 41, 65535, POSE)
    assert mm.describe_status(reading.status) == "ok"


@pytest.mark.parametrize(
    "status, word",
    [
        (0, "disabled"),
        (mm.STATUS_ENABLED | mm.STATUS_HOLDING, "holding"),
        (mm.STATUS_ENABLED | mm.STATUS_HOLDING | mm.STATUS_HEARTBEAT_LOST, "heartbeat-lost"),
        (mm.STATUS_ENABLED | mm.STATUS_FAULT | mm.STATUS_HEARTBEAT_LOST, "fault"),
    ],
)
def test_status_words(status, word):
    assert mm.describe_status(status) == word


def test_values_that_do_not_fit_are_refused_by_name():
    with pytest.raises(mm.RegisterError, match=r"setpoint position.y = 3000 m does not fit"):
        mm.encode_block((0.0, 3000.0) + POSE[2:])
    with pytest.raises(mm.RegisterError, match=r"linear.z = nan"):
        mm.encode_block(POSE[:9] + (float("nan"),) + POSE[10:])
    with pytest.raises(mm.RegisterError, match="expected 13 values"):
        mm.encode_block(POSE[:7])


def test_registers_of_another_device_are_refused():
    regs = [0] * mm.IR_COUNT
    with pytest.raises(mm.RegisterError, match="not a dockhil robot controller"):
        mm.decode_inputs(regs)
    with pytest.raises(mm.RegisterError, match="expected 31"):
        mm.decode_inputs(regs[:10])
