"""The A1 low-level UDP protocol, byte for byte against the vendor library's own test vectors.

``tests/data/a1-udp-test-vectors.txt`` (a copy of the team's ``shared/reference`` file, kept in the
repository so that CI on a bare clone checks it) holds datagrams produced (V1, V2) or accepted and
decoded (V3) by Unitree's v3.2 SDK, plus CRC spot values. Every vector is checked both ways.
"""

from __future__ import annotations

import re
import socket
from pathlib import Path

import numpy as np
import pytest
from a1_common.robot import a1
from a1_hw_bridge.link import LinkStats, RobotLink, accept_command, accept_state
from a1_hw_bridge.protocol import (
    LOW_CMD_SIZE,
    LOW_STATE_SIZE,
    POS_STOP_F,
    SERVO_MODE,
    VEL_STOP_F,
    Header,
    LowCmd,
    LowState,
    ProtocolError,
    crc32_words,
    pack_low_cmd,
    pack_low_state,
    packet_crc,
    unpack_low_cmd,
    unpack_low_state,
)

VECTORS_FILE = Path(__file__).resolve().parent / "data" / "a1-udp-test-vectors.txt"
f32 = np.float32


def load_vectors() -> dict[str, tuple[bytes, list[str]]]:
    """Vector name (V1..V4) -> (datagram, the comment lines after it)."""
    vectors: dict[str, tuple[bytes, list[str]]] = {}
    name = None
    for line in VECTORS_FILE.read_text().splitlines():
        header = re.match(r"## (V\d+):", line)
        if header:
            name = header.group(1)
        elif name and line and not line.startswith("#"):
            vectors[name] = (bytes.fromhex(line.strip()), [])
        elif name in vectors and line.startswith("#"):
            vectors[name][1].append(line[1:].strip())
    return vectors


VECTORS = load_vectors()


def reference_crc(data: bytes) -> int:
    """The SDK's CRC as the spec words it (section 4.1): bit by bit, MSB first, over LE words."""
    crc = 0xFFFFFFFF
    for (word,) in np.frombuffer(data, dtype="<u4").reshape(-1, 1):
        for bit in range(31, -1, -1):
            top = crc >> 31
            crc = (crc << 1) & 0xFFFFFFFF
            if top ^ ((int(word) >> bit) & 1):
                crc ^= 0x04C11DB7
    return crc


def a1_limits() -> tuple[np.ndarray, np.ndarray]:
    robot = a1()
    return robot.joint_lower_limits, robot.joint_upper_limits


# --- CRC ---------------------------------------------------------------------------------------------
def test_file_has_every_vector():
    assert sorted(VECTORS) == ["V1", "V2", "V3", "V4"]
    assert [len(VECTORS[v][0]) for v in ("V1", "V2", "V3", "V4")] == [610, 610, 771, 771]


@pytest.mark.parametrize(("hex_words", "expected"), [
    ("00000000", 0xC704DD7B), ("01000000", 0xC3C5C0CC), ("ff000000", 0x76F39DCF),
    ("3132333435363738", 0xFEFC54F9), ("00" * 764, 0xC54DCDDD),
])
def test_crc_worked_examples(hex_words, expected):
    data = bytes.fromhex(hex_words)
    assert crc32_words(data) == expected
    assert reference_crc(data) == expected


def test_crc_of_packets_and_against_the_bitwise_definition():
    assert packet_crc(VECTORS["V1"][0]) == 0x1359692F
    assert VECTORS["V1"][0][606:] == bytes.fromhex("2f695913")
    assert packet_crc(VECTORS["V4"][0]) == 0xC69014BF
    assert VECTORS["V4"][0][767:] == bytes.fromhex("bf1490c6")
    assert packet_crc(bytes(LOW_STATE_SIZE)) == 0xC54DCDDD  # 191 words of 771 zero bytes
    rng = np.random.default_rng(3)
    for n_words in (1, 2, 7, 151):
        data = rng.integers(0, 256, 4 * n_words, dtype=np.uint8).tobytes()
        assert crc32_words(data) == reference_crc(data)
    with pytest.raises(ValueError, match="whole 32-bit words"):
        crc32_words(b"abc")


# --- LowCmd ------------------------------------------------------------------------------------------
def v1_command() -> LowCmd:
    """UDP::InitCmdData: every slot servo mode with the PosStopF / VelStopF sentinels."""
    return LowCmd(mode=np.full(20, SERVO_MODE), q=np.full(20, POS_STOP_F), dq=np.full(20, VEL_STOP_F))


def v2_command() -> LowCmd:
    """The V2 inputs, computed in float32 arithmetic as the C harness did."""
    i = np.arange(20)
    return LowCmd(
        header=Header(0xFF, 0x1234, 0x5678, 0x9ABCDEF0, 0x3A), mode=np.where(i < 12, SERVO_MODE, 0),
        q=f32(0.1) * i.astype(f32) - f32(0.5), dq=f32(-0.25) * i.astype(f32),
        tau=f32(1.234) * (i - 6).astype(f32), kp=f32(20.0) + f32(3.3) * i.astype(f32),
        kd=f32(0.5) + f32(0.17) * i.astype(f32),
        motor_reserve=np.stack([0x11111111 * (i % 16), 0xA0000000 + i, np.full(20, 7)], axis=1),
        led=np.array([[10 + k, 20 + k, 30 + k] for k in range(4)]).reshape(-1),
        wireless_remote=bytes(3 * k for k in range(40)), reserve=0xCAFEBABE)


def test_v1_init_cmd_data_packs_and_unpacks_exactly():
    assert pack_low_cmd(v1_command(), position_limits=None) == VECTORS["V1"][0]
    cmd = unpack_low_cmd(VECTORS["V1"][0])
    assert np.all(cmd.mode == SERVO_MODE)
    assert np.all(cmd.q == float(f32(POS_STOP_F))) and np.all(cmd.dq == VEL_STOP_F)
    assert not cmd.tau.any() and not cmd.kp.any() and not cmd.kd.any()


def test_v2_every_field_packs_exactly():
    expected = VECTORS["V2"][0]
    packed = pack_low_cmd(v2_command(), position_limits=None)
    assert len(packed) == LOW_CMD_SIZE
    differing = [i for i, (a, b) in enumerate(zip(packed, expected, strict=True)) if a != b]
    assert not differing, f"bytes {differing[:10]} differ"


def test_v2_unpacks_to_its_inputs_at_wire_resolution():
    cmd = unpack_low_cmd(VECTORS["V2"][0])
    ref = v2_command()
    assert cmd.header == ref.header
    assert np.array_equal(cmd.mode, ref.mode)
    assert np.array_equal(cmd.q, ref.q.astype(float)) and np.array_equal(cmd.dq, ref.dq.astype(float))
    # Truncation toward zero to 1/256, 1/32, 1/16.
    for name, scale in (("tau", 256), ("kp", 32), ("kd", 16)):
        assert np.array_equal(getattr(cmd, name), np.trunc(getattr(ref, name).astype(float) * scale) / scale), name
    assert np.array_equal(cmd.motor_reserve, ref.motor_reserve)
    assert np.array_equal(cmd.led, ref.led) and cmd.wireless_remote == ref.wireless_remote
    assert cmd.reserve == 0xCAFEBABE
    assert pack_low_cmd(cmd, position_limits=None) == VECTORS["V2"][0]  # decode -> encode is the identity


def one_motor(**values: float) -> LowCmd:
    cmd = LowCmd(mode=np.full(20, SERVO_MODE))
    for name, value in values.items():
        getattr(cmd, name)[0] = value
    return cmd


def wire_int16(packet: bytes, field_offset: int) -> int:
    """int16 of motor 0 at ``field_offset`` within its record (tau +9, Kp +11, Kd +13)."""
    return int.from_bytes(packet[10 + field_offset:12 + field_offset], "little", signed=True)


@pytest.mark.parametrize(("field", "value", "offset", "sdk_wrapped", "clipped"), [
    ("tau", 200.0, 9, -14336, 32767), ("kp", 1500.0, 11, -17536, 32767), ("kd", -3000.0, 13, 17536, -32768),
])
def test_int16_overflow_is_refused_or_clipped_never_wrapped(field, value, offset, sdk_wrapped, clipped):
    with pytest.raises(ProtocolError, match=rf"{field}\[0\] = {value} does not fit the int16 wire field: allowed \["):
        pack_low_cmd(one_motor(**{field: value}), position_limits=None)
    packet = pack_low_cmd(one_motor(**{field: value}), position_limits=None, clip=True)
    assert wire_int16(packet, offset) == clipped != sdk_wrapped
    assert unpack_low_cmd(packet) is not None  # still a valid datagram (CRC over the clipped bytes)


@pytest.mark.parametrize(("field", "value", "offset", "raw"), [
    ("tau", -1.999, 9, -511), ("kp", 1.99, 11, 63), ("kd", -0.99, 13, -15), ("tau", -0.001, 9, 0),
    ("tau", 127.99, 9, 32765), ("kd", 2047.9, 13, 32766),
])
def test_truncation_toward_zero_like_the_sdk(field, value, offset, raw):
    assert wire_int16(pack_low_cmd(one_motor(**{field: value}), position_limits=None), offset) == raw


@pytest.mark.parametrize(("field", "value"), [
    ("q", float("nan")), ("dq", float("inf")), ("tau", float("nan")), ("kp", float("-inf")), ("kd", float("nan")),
    ("q", 1e39), ("dq", -1e39),  # finite doubles that overflow float32 to inf
])
def test_nan_and_inf_are_never_packed(field, value):
    with pytest.raises(ProtocolError, match=rf"{field}\[0\] = .* is not a finite float32: never sent"):
        pack_low_cmd(one_motor(**{field: value}), position_limits=a1_limits(), clip=True)


def test_position_targets_clamped_to_the_a1_joint_limits():
    lower, upper = a1_limits()
    q = np.zeros(20)
    q[:12] = np.tile([1.5, -2.0, -0.1], 4)  # hip above, thigh below, calf above their ranges
    q[12:] = 9.0  # unused slots are carried as they are
    q[5] = -1.5  # FL calf inside its range stays
    packed = unpack_low_cmd(pack_low_cmd(LowCmd(q=q), position_limits=(lower, upper)))
    expected = np.clip(q[:12], lower, upper)
    expected[5] = -1.5
    assert np.allclose(packed.q[:12], expected, atol=1e-6)
    assert packed.q[0] == pytest.approx(0.802851, abs=1e-6) and packed.q[2] == pytest.approx(-0.916298, abs=1e-6)
    assert np.all(packed.q[12:] == 9.0)


@pytest.mark.parametrize(("changes", "match"), [
    ({"header": Header(comm_version=70000)}, r"comm_version = 70000 outside \[0, 65535\]"),
    ({"header": Header(level_flag=256)}, r"level_flag = 256 outside \[0, 255\]"),
    ({"mode": np.full(20, 300)}, r"mode = 300 outside \[0, 255\]"),
    ({"q": np.zeros(12)}, r"q must have shape \(20,\)"),
    ({"wireless_remote": bytes(39)}, r"wireless_remote must be 40 bytes"),
    ({"reserve": -1}, r"reserve = -1 outside"),
])
def test_bad_header_and_shape_values_are_named(changes, match):
    cmd = LowCmd()
    for name, value in changes.items():
        setattr(cmd, name, value)
    with pytest.raises(ProtocolError, match=match):
        pack_low_cmd(cmd, position_limits=None)


# --- LowState ----------------------------------------------------------------------------------------
def v3_state() -> LowState:
    """The V3 inputs ("built as" in the vector file)."""
    i = np.arange(20)
    return LowState(
        header=Header(0xFF, 0x0102, 0x0304, 0x05060708, 9), quaternion=np.array([0.9, 0.1, -0.2, 0.3]),
        gyroscope=np.array([1.5, -2.5, 3.5]), accelerometer=np.array([0.25, -9.81, 0.125]),
        rpy=np.array([0.01, -0.02, 0.03]), imu_temperature=41, mode=np.where(i < 12, SERVO_MODE, 0),
        q=0.05 * i, dq=-0.5 * i, ddq=100 * i - 700, tau_est=(37 * i - 300) / 256.0, q_raw=0.07 * i, dq_raw=0.11 * i,
        ddq_raw=-3 * i, temperature=30 + i,
        motor_reserve=np.stack([(0x01020304 * i) % (1 << 32), i], axis=1),
        foot_force=np.array([11, -22, 33, 444]), foot_force_est=np.array([5, 6, 7, 8]), tick=123456789,
        wireless_remote=bytes(100 + k for k in range(40)), reserve=0xDEADBEEF)


def sdk_decoded_v3() -> dict[str, list[float]]:
    """The SDK's printout of V3 after GetRecv, keyed by line tag (hdr, imu, m0..m19, ff, remote)."""
    lines = [line for line in VECTORS["V3"][1] if re.match(r"(hdr|imu|m\d+|ff|remote) ", line)]
    return {line.split()[0]: line.split()[1:] for line in lines}


def test_v3_state_unpacks_to_what_the_sdk_decoded():
    state = unpack_low_state(VECTORS["V3"][0])
    sdk = sdk_decoded_v3()
    assert [state.header.level_flag, state.header.comm_version, state.header.robot_id, state.header.sn,
            state.header.bandwidth] == [int(v) for v in sdk["hdr"]]
    imu = sdk["imu"]  # q w x y z gyro . . . acc . . . rpy . . . T t
    assert np.allclose(state.quaternion, [float(v) for v in imu[1:5]], atol=5e-7)
    assert np.allclose(state.gyroscope, [float(v) for v in imu[6:9]], atol=5e-7)
    assert np.allclose(state.accelerometer, [float(v) for v in imu[10:13]], atol=5e-7)
    assert np.allclose(state.rpy, [float(v) for v in imu[14:17]], atol=5e-7)
    assert state.imu_temperature == int(imu[18])
    for m in range(20):
        v = dict(zip(sdk[f"m{m}"][0:-3:2], sdk[f"m{m}"][1:-3:2], strict=True))
        assert state.mode[m] == int(v["mode"])
        for ours, theirs in (("q", "q"), ("dq", "dq"), ("ddq", "ddq"), ("tau_est", "tauEst"), ("q_raw", "qraw"),
                             ("dq_raw", "dqraw"), ("ddq_raw", "ddqraw"), ("temperature", "T")):
            assert getattr(state, ours)[m] == pytest.approx(float(v[theirs]), abs=5e-7), (m, ours)
        assert [f"{r:08x}" for r in state.motor_reserve[m]] == sdk[f"m{m}"][-2:]
    ff = sdk["ff"]
    assert state.foot_force.tolist() == [int(v) for v in ff[0:4]]
    assert state.tick == int(ff[ff.index("tick") + 1]) and f"{state.reserve:x}" == ff[ff.index("reserve") + 1]
    assert state.wireless_remote.hex() == sdk["remote"][0]
    # The SDK does not copy footForceEst into its struct; the bytes on the wire hold (5, 6, 7, 8).
    assert state.foot_force_est.tolist() == [5, 6, 7, 8]


def test_v3_state_packs_exactly_from_its_inputs():
    assert pack_low_state(v3_state()) == VECTORS["V3"][0]
    assert pack_low_state(unpack_low_state(VECTORS["V3"][0])) == VECTORS["V3"][0]


def test_v4_zero_state_packs_exactly():
    zero = LowState(quaternion=np.zeros(4))
    assert pack_low_state(zero) == VECTORS["V4"][0]
    assert unpack_low_state(VECTORS["V4"][0]).header.level_flag == 0xFF


def test_state_int16_fields_refused_or_clipped():
    with pytest.raises(ProtocolError, match=r"tau_est\[3\] = 200.0 does not fit"):
        pack_low_state(LowState(tau_est=np.where(np.arange(20) == 3, 200.0, 0.0)))
    with pytest.raises(ProtocolError, match=r"foot_force\[1\] = 40000.0 does not fit"):
        pack_low_state(LowState(foot_force=np.array([0.0, 40000.0, 0.0, 0.0])))
    clipped = unpack_low_state(pack_low_state(LowState(foot_force=np.array([0.0, 40000.0, -40000.0, 0.0])),
                                              clip=True))
    assert clipped.foot_force.tolist() == [0, 32767, -32768, 0]
    with pytest.raises(ProtocolError, match=r"gyroscope\[2\] = nan is not a finite float32"):
        pack_low_state(LowState(gyroscope=np.array([0.0, 0.0, np.nan])))


# --- rejection of bad datagrams ------------------------------------------------------------------------
@pytest.mark.parametrize("size", [770, 772, 0, 610])
def test_wrong_size_state_is_refused_and_counted(size):
    data = (VECTORS["V3"][0] + bytes(10))[:size]
    with pytest.raises(ProtocolError, match=f"LowState must be 771 bytes, got {size}") as info:
        unpack_low_state(data)
    assert info.value.reason == "size"
    stats = LinkStats()
    assert accept_state(data, stats) is None
    assert (stats.received, stats.wrong_size, stats.bad_crc, stats.accepted) == (1, 1, 0, 0)


@pytest.mark.parametrize("byte", [0, 100, 763, 767, 770])
def test_bad_crc_state_is_refused_and_counted(byte):
    data = bytearray(VECTORS["V3"][0])
    data[byte] ^= 0x01
    with pytest.raises(ProtocolError, match="LowState CRC mismatch") as info:
        unpack_low_state(bytes(data))
    assert info.value.reason == "crc"
    stats = LinkStats()
    assert accept_state(bytes(data), stats) is None
    assert (stats.bad_crc, stats.wrong_size, stats.dropped) == (1, 0, 1)


def test_bytes_outside_the_crc_span_are_not_checked():
    """As in the SDK: the CRC covers the first len//4 - 1 words only (LowState: bytes 0..763)."""
    data = bytearray(VECTORS["V3"][0])
    data[765] ^= 0xFF
    assert unpack_low_state(bytes(data)).reserve != 0xDEADBEEF


def test_command_datagrams_checked_on_the_robot_side():
    stats = LinkStats()
    good = VECTORS["V2"][0]
    assert accept_command(good, stats) is not None
    assert accept_command(good[:-1], stats) is None
    corrupt = bytearray(good)
    corrupt[50] ^= 0x80
    assert accept_command(bytes(corrupt), stats) is None
    high_level = pack_low_cmd(LowCmd(header=Header(level_flag=0x00)), position_limits=None)
    assert accept_command(high_level, stats) is None
    assert (stats.received, stats.accepted, stats.wrong_size, stats.bad_crc, stats.bad_level) == (4, 1, 1, 1, 1)


def test_robot_link_keeps_the_newest_valid_state_and_counts_the_rest():
    robot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    robot.bind(("127.0.0.1", 0))
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    link = RobotLink("127.0.0.1", robot.getsockname()[1], "127.0.0.1", 0)
    try:
        assert link.receive(0.01) is None
        assert link.send(pack_low_cmd(LowCmd(), position_limits=None))
        _, client = robot.recvfrom(2048)
        older = pack_low_state(LowState(tick=1))
        newer = pack_low_state(LowState(tick=2))
        corrupt = bytearray(newer)
        corrupt[20] ^= 1
        for datagram in (older, newer, bytes(corrupt), newer[:700]):
            robot.sendto(datagram, client)
        stranger.sendto(pack_low_state(LowState(tick=99)), client)  # not from the robot's address: never seen
        state = link.receive(1.0)
        assert state is not None and state.tick == 2
        assert (link.stats.accepted, link.stats.bad_crc, link.stats.wrong_size) == (2, 1, 1)
        assert link.receive(0.05) is None
    finally:
        link.close()
        robot.close()
        stranger.close()
