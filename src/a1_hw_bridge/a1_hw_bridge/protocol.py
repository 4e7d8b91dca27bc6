"""The Unitree A1 low-level UDP protocol (unitree_legged_sdk v3.2 wire format), in Python.

No vendor binary: the layouts, scalings and CRC follow ``shared/reference/a1-udp-protocol.md`` and
are checked byte for byte against the vendor library's test vectors (tests/test_a1_udp_protocol.py).

- LowCmd (client -> robot): 610 bytes; LowState (robot -> client): 771 bytes. Little-endian,
  packed, IEEE-754 float32. 20 motor slots, of which 0..11 are the A1's joints in the order
  FR, FL, RR, RL x (hip, thigh, calf) -- the stack's joint order, so no remapping.
- Per motor command: mode (0x0A servo, 0x00 idle), q [rad] and dq [rad/s] as float32,
  tau [N m] x 256, Kp [N m/rad] x 32 and Kd [N m s/rad] x 16 truncated into int16 fields.
  The vendor SDK wraps out-of-range values silently (tau = 200 N m goes out as -56 N m); this
  packer never does: such values are rejected with the field named, or clipped on request.
  NaN/inf are never packed. Commanded positions of motors 0..11 are clamped to the joint limits
  (the SDK's ``Safety::PositionLimit``), unless the caller passes ``position_limits=None``.
- CRC: CRC-32/MPEG-2 (poly 0x04C11DB7, init 0xFFFFFFFF, MSB first, no reflection, no final
  XOR) over the first ``len // 4 - 1`` little-endian 32-bit words, stored as LE uint32 in the
  last 4 bytes. A datagram of the wrong size or with a bad CRC is refused (ProtocolError).
- IMU quaternion on the wire is (w, x, y, z); body-frame gyroscope [rad/s] and accelerometer
  (specific force) [m/s^2]; rpy [rad]. Foot force: raw int16 sensor units, leg order FR FL RR RL.
  tick: the robot's clock in microseconds (uint32, wraps after about 71.6 minutes).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

LOW_CMD_SIZE = 610  # [bytes]
LOW_STATE_SIZE = 771  # [bytes]
LOWLEVEL = 0xFF  # levelFlag of low-level datagrams
NUM_MOTOR_SLOTS = 20
NUM_ROBOT_MOTORS = 12  # slots 0..11 are the A1's joints
SERVO_MODE = 0x0A  # closed-loop FOC: tau = tau_ff + Kp (q* - q) + Kd (dq* - dq)
IDLE_MODE = 0x00
POS_STOP_F = 2.146e9  # q sentinel: "no position term" (as float32)
VEL_STOP_F = 16000.0  # dq sentinel: "no velocity term"
TAU_SCALE = 256.0  # wire int16 = trunc(tau * 256)
KP_SCALE = 32.0
KD_SCALE = 16.0
TAU_EST_SCALE = 256.0  # state tauEst int16 = tau * 256

DEFAULT_ROBOT_IP = "192.168.123.10"  # the A1's motor controller board
DEFAULT_ROBOT_PORT = 8007
DEFAULT_LOCAL_PORT = 8080

_INT16 = (-32768, 32767)
_MOTOR_CMD_DTYPE = np.dtype([
    ("mode", "u1"), ("q", "<f4"), ("dq", "<f4"), ("tau", "<i2"), ("kp", "<i2"), ("kd", "<i2"),
    ("reserve", "<u4", (3,)),
])
_HEADER = [("level_flag", "u1"), ("comm_version", "<u2"), ("robot_id", "<u2"), ("sn", "<u4"),
           ("bandwidth", "u1")]
LOW_CMD_DTYPE = np.dtype([
    *_HEADER, ("motor", _MOTOR_CMD_DTYPE, (NUM_MOTOR_SLOTS,)), ("led", "u1", (12,)),
    ("wireless_remote", "u1", (40,)), ("reserve", "<u4"), ("crc", "<u4"),
])
_MOTOR_STATE_DTYPE = np.dtype([
    ("mode", "u1"), ("q", "<f4"), ("dq", "<f4"), ("ddq", "<i2"), ("tau_est", "<i2"), ("q_raw", "<f4"),
    ("dq_raw", "<f4"), ("ddq_raw", "<i2"), ("temperature", "i1"), ("reserve", "<u4", (2,)),
])
LOW_STATE_DTYPE = np.dtype([
    *_HEADER, ("quaternion", "<f4", (4,)), ("gyroscope", "<f4", (3,)), ("accelerometer", "<f4", (3,)),
    ("rpy", "<f4", (3,)), ("imu_temperature", "i1"), ("motor", _MOTOR_STATE_DTYPE, (NUM_MOTOR_SLOTS,)),
    ("foot_force", "<i2", (4,)), ("foot_force_est", "<i2", (4,)), ("tick", "<u4"),
    ("wireless_remote", "u1", (40,)), ("reserve", "<u4"), ("crc", "<u4"),
])
assert _MOTOR_CMD_DTYPE.itemsize == 27 and LOW_CMD_DTYPE.itemsize == LOW_CMD_SIZE
assert _MOTOR_STATE_DTYPE.itemsize == 32 and LOW_STATE_DTYPE.itemsize == LOW_STATE_SIZE


class ProtocolError(ValueError):
    """A datagram that must not be sent or used. ``reason``: size, crc, level_flag or value."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


# --- CRC ------------------------------------------------------------------------------------------
_BIT_REVERSED_BYTES = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))


def crc32_words(data: bytes) -> int:
    """The A1's CRC-32 of ``data`` read as little-endian 32-bit words (len a multiple of 4).

    Same result as the bitwise MSB-first loop of the SDK; computed with zlib's reflected CRC-32
    on the bit-reversed stream (the two algorithms are mirror images of each other), so a
    packet costs microseconds instead of a Python loop over 6000 bits.
    """
    if len(data) % 4:
        raise ValueError(f"CRC input must be whole 32-bit words, got {len(data)} bytes")
    msb_first = np.frombuffer(data, dtype="<u4").astype(">u4").tobytes()
    reflected = zlib.crc32(msb_first.translate(_BIT_REVERSED_BYTES)) ^ 0xFFFFFFFF
    return int(f"{reflected:032b}"[::-1], 2)


def packet_crc(packet: bytes) -> int:
    """CRC of a whole datagram as the SDK computes it: over its first ``len // 4 - 1`` words."""
    return crc32_words(packet[: 4 * (len(packet) // 4 - 1)])


def _seal(record: np.ndarray, wireless_remote: bytes, reserve: int) -> bytes:
    """Fill the fields both datagrams end with (remote, reserve), then the CRC; the wire bytes."""
    record["wireless_remote"] = _blob("wireless_remote", wireless_remote, 40)
    record["reserve"] = _integers("reserve", reserve, 32)
    raw = bytearray(record.tobytes())
    raw[-4:] = packet_crc(bytes(raw)).to_bytes(4, "little")
    return bytes(raw)


def _open(data: bytes, size: int, dtype: np.dtype, what: str) -> np.ndarray:
    if len(data) != size:
        raise ProtocolError("size", f"{what} must be {size} bytes, got {len(data)}")
    stored = int.from_bytes(data[-4:], "little")
    computed = packet_crc(data)
    if stored != computed:
        raise ProtocolError("crc", f"{what} CRC mismatch: stored 0x{stored:08X}, computed 0x{computed:08X}")
    return np.frombuffer(data, dtype=dtype)[0]


# --- value checks -----------------------------------------------------------------------------------
def _float32(name: str, values: np.ndarray) -> np.ndarray:
    """``values`` as float32, refusing NaN/inf and magnitudes float32 cannot hold."""
    v64 = np.asarray(values, dtype=float)
    with np.errstate(over="ignore"):
        v32 = v64.astype(np.float32)
    bad = np.flatnonzero(~np.isfinite(v32))
    if bad.size:
        i = int(bad[0])
        raise ProtocolError("value", f"{name}[{i}] = {float(v64.flat[i])!r} is not a finite float32: never sent")
    return v32


def _scaled_int16(name: str, values: np.ndarray, scale: float, *, clip: bool, rounding: str) -> np.ndarray:
    """float32(value) x scale into int16 (truncated like the SDK, or rounded), clipped or refused."""
    scaled = _float32(name, values).astype(np.float64) * scale  # exact: scale is a power of two
    scaled = np.trunc(scaled) if rounding == "trunc" else np.round(scaled)
    lo, hi = _INT16
    outside = np.flatnonzero((scaled < lo) | (scaled > hi))
    if outside.size and not clip:
        i = int(outside[0])
        value = float(np.asarray(values, dtype=float).flat[i])
        raise ProtocolError("value", f"{name}[{i}] = {value!r} does not fit the int16 wire field: "
                                     f"allowed [{lo / scale}, {hi / scale}] (the SDK would wrap it)")
    return np.clip(scaled, lo, hi).astype(np.int16)


def _integers(name: str, values, bits: int, *, signed: bool = False) -> np.ndarray:
    arr = np.asarray(values)
    if arr.dtype.kind not in "iu" and not (arr.dtype.kind == "f" and np.all(arr == np.round(arr))):
        raise ProtocolError("value", f"{name} must be integers, got {values!r}")
    arr = arr.astype(np.int64)
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    outside = np.flatnonzero((arr < lo) | (arr > hi))
    if outside.size:
        i = int(outside[0])
        raise ProtocolError("value", f"{name} = {int(arr.flat[i])} outside [{lo}, {hi}]")
    return arr


def _slots(name: str, values, shape: tuple[int, ...] = (NUM_MOTOR_SLOTS,)) -> np.ndarray:
    arr = np.asarray(values)
    if arr.shape != shape:
        raise ProtocolError("value", f"{name} must have shape {shape}, got {arr.shape}")
    return arr


def _blob(name: str, value: bytes, size: int) -> np.ndarray:
    if len(value) != size:
        raise ProtocolError("value", f"{name} must be {size} bytes, got {len(value)}")
    return np.frombuffer(bytes(value), dtype=np.uint8)


def _zeros() -> np.ndarray:
    return np.zeros(NUM_MOTOR_SLOTS)


@dataclass
class Header:
    """The first 10 bytes of every A1 datagram."""

    level_flag: int = LOWLEVEL
    comm_version: int = 0
    robot_id: int = 0
    sn: int = 0
    bandwidth: int = 0

    def write(self, record: np.ndarray) -> None:
        for name, bits in (("level_flag", 8), ("comm_version", 16), ("robot_id", 16), ("sn", 32),
                           ("bandwidth", 8)):
            record[name] = _integers(name, getattr(self, name), bits)

    @classmethod
    def read(cls, record: np.ndarray) -> Header:
        return cls(*(int(record[n]) for n in ("level_flag", "comm_version", "robot_id", "sn", "bandwidth")))


# --- LowCmd -----------------------------------------------------------------------------------------
@dataclass
class LowCmd:
    """A low-level command in physical units, one entry per motor slot (20; 0..11 are the joints)."""

    header: Header = field(default_factory=Header)
    mode: np.ndarray = field(default_factory=lambda: np.zeros(NUM_MOTOR_SLOTS, dtype=int))
    q: np.ndarray = field(default_factory=_zeros)  # [rad]
    dq: np.ndarray = field(default_factory=_zeros)  # [rad/s]
    tau: np.ndarray = field(default_factory=_zeros)  # feed-forward [N m]
    kp: np.ndarray = field(default_factory=_zeros)  # [N m / rad]
    kd: np.ndarray = field(default_factory=_zeros)  # [N m s / rad]
    motor_reserve: np.ndarray = field(default_factory=lambda: np.zeros((NUM_MOTOR_SLOTS, 3), dtype=int))
    led: np.ndarray = field(default_factory=lambda: np.zeros(12, dtype=int))  # 4 x (r, g, b)
    wireless_remote: bytes = bytes(40)
    reserve: int = 0


def pack_low_cmd(cmd: LowCmd, *, position_limits: tuple[np.ndarray, np.ndarray] | None,
                 clip: bool = False) -> bytes:
    """The 610-byte datagram of ``cmd``, CRC included.

    ``position_limits`` = (lower, upper) [rad] for motors 0..11 clamps the commanded q into the
    joint range (pass ``None`` only to reproduce raw SDK datagrams). Values the int16 fields cannot
    hold raise ProtocolError naming the field, or are clipped to the representable range if
    ``clip``; NaN/inf always raise.
    """
    record = np.zeros((), dtype=LOW_CMD_DTYPE)
    cmd.header.write(record)
    motors = record["motor"]
    motors["mode"] = _integers("mode", _slots("mode", cmd.mode), 8)
    q = _float32("q", _slots("q", cmd.q))
    if position_limits is not None:
        lower, upper = (np.asarray(v, dtype=np.float64) for v in position_limits)
        q = q.copy()
        q[:NUM_ROBOT_MOTORS] = np.clip(q[:NUM_ROBOT_MOTORS].astype(np.float64), lower, upper).astype(np.float32)
    motors["q"] = q
    motors["dq"] = _float32("dq", _slots("dq", cmd.dq))
    for name, scale in (("tau", TAU_SCALE), ("kp", KP_SCALE), ("kd", KD_SCALE)):
        motors[name] = _scaled_int16(name, _slots(name, getattr(cmd, name)), scale, clip=clip, rounding="trunc")
    motors["reserve"] = _integers("motor_reserve", _slots("motor_reserve", cmd.motor_reserve,
                                                           (NUM_MOTOR_SLOTS, 3)), 32)
    record["led"] = _integers("led", _slots("led", cmd.led, (12,)), 8)
    return _seal(record, cmd.wireless_remote, cmd.reserve)


def unpack_low_cmd(data: bytes) -> LowCmd:
    """Decode a 610-byte command; ProtocolError if the size or the CRC is wrong."""
    record = _open(data, LOW_CMD_SIZE, LOW_CMD_DTYPE, "LowCmd")
    motors = record["motor"]
    return LowCmd(
        header=Header.read(record), mode=motors["mode"].astype(int), q=motors["q"].astype(float),
        dq=motors["dq"].astype(float), tau=motors["tau"] / TAU_SCALE, kp=motors["kp"] / KP_SCALE,
        kd=motors["kd"] / KD_SCALE, motor_reserve=motors["reserve"].astype(np.int64),
        led=record["led"].astype(int), wireless_remote=record["wireless_remote"].tobytes(),
        reserve=int(record["reserve"]))


# --- LowState ---------------------------------------------------------------------------------------
def _zeros3() -> np.ndarray:
    return np.zeros(3)


def _int_slots(shape: tuple[int, ...] = (NUM_MOTOR_SLOTS,)):
    return lambda: np.zeros(shape, dtype=int)


@dataclass
class LowState:
    """A low-level state in physical units (20 motor slots; 0..11 are the joints)."""

    header: Header = field(default_factory=Header)
    quaternion: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))  # (w, x, y, z)
    gyroscope: np.ndarray = field(default_factory=_zeros3)  # body frame [rad/s]
    accelerometer: np.ndarray = field(default_factory=_zeros3)  # specific force, body frame [m/s^2]
    rpy: np.ndarray = field(default_factory=_zeros3)  # [rad]
    imu_temperature: int = 0  # [deg C]
    mode: np.ndarray = field(default_factory=_int_slots())
    q: np.ndarray = field(default_factory=_zeros)  # [rad]
    dq: np.ndarray = field(default_factory=_zeros)  # [rad/s]
    ddq: np.ndarray = field(default_factory=_int_slots())  # raw int16, unscaled (unit undocumented)
    tau_est: np.ndarray = field(default_factory=_zeros)  # estimated joint torque [N m]
    q_raw: np.ndarray = field(default_factory=_zeros)
    dq_raw: np.ndarray = field(default_factory=_zeros)
    ddq_raw: np.ndarray = field(default_factory=_int_slots())
    temperature: np.ndarray = field(default_factory=_int_slots())  # [deg C]
    motor_reserve: np.ndarray = field(default_factory=_int_slots((NUM_MOTOR_SLOTS, 2)))
    foot_force: np.ndarray = field(default_factory=_int_slots((4,)))  # raw sensor units, FR FL RR RL
    foot_force_est: np.ndarray = field(default_factory=_int_slots((4,)))
    tick: int = 0  # robot clock [us]
    wireless_remote: bytes = bytes(40)
    reserve: int = 0


def pack_low_state(state: LowState, *, clip: bool = False) -> bytes:
    """The 771-byte datagram of ``state`` (what the robot sends), CRC included.

    tauEst is rounded to the nearest 1/256 N m; int16 overflow raises (or clips if ``clip``).
    """
    record = np.zeros((), dtype=LOW_STATE_DTYPE)
    state.header.write(record)
    for name, size in (("quaternion", 4), ("gyroscope", 3), ("accelerometer", 3), ("rpy", 3)):
        record[name] = _float32(name, _slots(name, getattr(state, name), (size,)))
    record["imu_temperature"] = _integers("imu_temperature", state.imu_temperature, 8, signed=True)
    motors = record["motor"]
    motors["mode"] = _integers("mode", _slots("mode", state.mode), 8)
    for name in ("q", "dq", "q_raw", "dq_raw"):
        motors[name] = _float32(name, _slots(name, getattr(state, name)))
    motors["tau_est"] = _scaled_int16("tau_est", _slots("tau_est", state.tau_est), TAU_EST_SCALE, clip=clip,
                                      rounding="round")
    for name in ("ddq", "ddq_raw"):
        motors[name] = _scaled_int16(name, _slots(name, getattr(state, name)), 1.0, clip=clip, rounding="round")
    motors["temperature"] = _integers("temperature", _slots("temperature", state.temperature), 8, signed=True)
    motors["reserve"] = _integers("motor_reserve", _slots("motor_reserve", state.motor_reserve,
                                                           (NUM_MOTOR_SLOTS, 2)), 32)
    for name in ("foot_force", "foot_force_est"):
        record[name] = _scaled_int16(name, _slots(name, getattr(state, name), (4,)), 1.0, clip=clip,
                                     rounding="round")
    record["tick"] = _integers("tick", state.tick, 32)
    return _seal(record, state.wireless_remote, state.reserve)


def unpack_low_state(data: bytes) -> LowState:
    """Decode a 771-byte state; ProtocolError if the size or the CRC is wrong."""
    record = _open(data, LOW_STATE_SIZE, LOW_STATE_DTYPE, "LowState")
    motors = record["motor"]
    as_float = lambda a: np.asarray(a, dtype=float)  # noqa: E731
    return LowState(
        header=Header.read(record), quaternion=as_float(record["quaternion"]),
        gyroscope=as_float(record["gyroscope"]), accelerometer=as_float(record["accelerometer"]),
        rpy=as_float(record["rpy"]), imu_temperature=int(record["imu_temperature"]),
        mode=motors["mode"].astype(int), q=as_float(motors["q"]), dq=as_float(motors["dq"]),
        ddq=motors["ddq"].astype(int), tau_est=motors["tau_est"] / TAU_EST_SCALE, q_raw=as_float(motors["q_raw"]),
        dq_raw=as_float(motors["dq_raw"]), ddq_raw=motors["ddq_raw"].astype(int),
        temperature=motors["temperature"].astype(int), motor_reserve=motors["reserve"].astype(np.int64),
        foot_force=record["foot_force"].astype(int), foot_force_est=record["foot_force_est"].astype(int),
        tick=int(record["tick"]), wireless_remote=record["wireless_remote"].tobytes(),
        reserve=int(record["reserve"]))
