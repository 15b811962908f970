"""Messages of the command channel: tags, codes and body layouts.

Mirrors, by hand, the tables of the Rust crate ``foc-protocol``
(``protocol/src/message/``, ``protocol/src/scope.rs``,
``protocol/src/config.rs``): every body a fixed sequence of little-endian
fields, ``f32`` as IEEE 754 bits. Request bodies are built by the
``body_*`` functions (one per request with a body), reply bodies decoded by
the ``decode_*`` functions (which raise
:class:`~foc_drive.errors.ProtocolError` when a body does not have its exact
layout).

The Rust side is the reference, and these layouts are checked against it:
``protocol/tests/layouts.rs`` encodes every request and reply variant of
the current protocol version with the crate's own encoder and writes them,
with the code tables and constants mirrored here, to
``python/tests/vectors/protocol-v<N>.json``; ``python/tests/test_layouts.py``
builds every request body with the ``body_*`` functions, decodes every reply
body with the ``decode_*`` functions and compares tags, codes, field names
and constants. A message or code added on the Rust side fails that test
until it is mirrored here.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

from .errors import ProtocolError

#: Protocol versions this package speaks (4 adds the scope, 5 the angle in
#: use in the telemetry's flags).
SUPPORTED_PROTOCOL_VERSIONS = (3, 4, 5)
#: First protocol version with the scope.
SCOPE_PROTOCOL_VERSION = 4
#: Record bytes per configuration chunk.
CHUNK_BYTES = 48
#: Largest configuration record the link moves [bytes] (2048 since the
#: record keeps the anticogging map and the angle correction, 320 before).
MAX_RECORD = 2048
#: Most values in one ``ScopeData`` reply.
SCOPE_DATA_MAX = 12
#: Scope signal slots.
SCOPE_SLOTS = 8
#: Unused scope slot.
SCOPE_UNUSED = 0xFF


class Tag(enum.IntEnum):
    """Message tags (host to device below 0x80, device to host from 0x80)."""

    PING = 0x01
    KEEP_ALIVE = 0x02
    SET_COMMAND = 0x10
    SET_LIMITS = 0x11
    SET_CURRENT_GAINS = 0x12
    SET_SPEED_GAINS = 0x13
    SET_POSITION_GAINS = 0x14
    SET_DIVIDERS = 0x15
    SET_WATCHDOG = 0x16
    SET_JOINT = 0x17
    SET_PARAM = 0x18
    RUN_CALIBRATION = 0x20
    READ_FAULTS = 0x21
    CLEAR_FAULTS = 0x22
    READ_PARAM = 0x23
    READ_TELEMETRY = 0x24
    READ_JOINT = 0x25
    START_HOMING = 0x26
    READ_HOMING = 0x27
    START_TELEMETRY = 0x30
    STOP_TELEMETRY = 0x31
    READ_CONFIG = 0x40
    WRITE_CONFIG = 0x41
    STORE = 0x42
    SET_SCOPE = 0x50
    ARM_SCOPE = 0x51
    TRIGGER_SCOPE = 0x52
    READ_SCOPE = 0x53
    READ_SCOPE_DATA = 0x54

    ACK = 0x80
    NACK = 0x81
    HELLO = 0x82
    FAULTS = 0x83
    PARAM = 0x84
    TELEMETRY = 0x85
    STREAM = 0x86
    CONFIG_CHUNK = 0x87
    JOINT = 0x88
    HOMING = 0x89
    SCOPE = 0x8A
    SCOPE_DATA = 0x8B


class ErrorCode(enum.IntEnum):
    """A Nack's reason (names as ``ErrorCode`` in ``message.rs``)."""

    Malformed = 1
    BadCrc = 2
    UnknownMessage = 3
    OutOfRange = 4
    Faulted = 5
    Busy = 6
    NotCalibrated = 7
    NotDisabled = 8
    Unsupported = 9
    StoreFailed = 10
    BadRecord = 11
    NothingStored = 12
    ScopeState = 13
    NeedsAngleSensor = 14


ERROR_TEXT: Dict[int, str] = {
    ErrorCode.Malformed: "malformed frame",
    ErrorCode.BadCrc: "bad CRC",
    ErrorCode.UnknownMessage: "unknown message",
    ErrorCode.OutOfRange: "out of range",
    ErrorCode.Faulted: "a fault is latched (clear it first)",
    ErrorCode.Busy: "busy",
    ErrorCode.NotCalibrated: "not calibrated",
    ErrorCode.NotDisabled: "only allowed while disabled",
    ErrorCode.Unsupported: "not supported by this device",
    ErrorCode.StoreFailed: "the flash store failed",
    ErrorCode.BadRecord: (
        "configuration record refused (incomplete, corrupt, other version "
        "or out of range; nothing applied)"
    ),
    ErrorCode.NothingStored: "nothing is stored",
    ErrorCode.ScopeState: "the scope is not in the state this needs",
    ErrorCode.NeedsAngleSensor: (
        "the drive runs sensorless: torque, position and impedance need the "
        "angle sensor (velocity and open loop are taken)"
    ),
}


class Mode(enum.IntEnum):
    """Control mode (``SetCommand``'s and telemetry's ``mode``)."""

    Disabled = 0
    Torque = 1
    Velocity = 2
    Position = 3
    OpenLoop = 4
    Impedance = 5


class AngleInUse(enum.IntEnum):
    """Where the current loop's angle came from (telemetry, protocol 5)."""

    SENSOR = 0
    """The angle sensor."""
    SENSORLESS = 1
    """The flux observer (or the start's field): configured sensorless."""
    OBSERVER = 2
    """Halls + sensorless: the observer beside the sensor, above its speed."""
    LIMP_HOME = 3
    """The observer, because the angle sensor failed."""


class Fault(enum.IntEnum):
    """Fault codes (``FaultSet`` bit n = fault code n)."""

    OverCurrentPhase = 1
    OverCurrentVector = 2
    BusOverVoltage = 3
    BusUnderVoltage = 4
    CurrentSumMismatch = 5
    AngleSensorError = 6
    AngleSensorImplausible = 7
    NonFinite = 8
    LoopOverrun = 9
    CommandTimeout = 10
    CurrentSenseError = 11
    BusSenseError = 12
    OverTemperature = 13
    GateDriverFault = 14
    PwmError = 15
    CalibrationFailed = 16
    Watchdog = 17
    AngleSensorStuck = 18
    OverSpeed = 19
    SpeedRunaway = 20
    TravelLimit = 21
    ObserverLostLock = 22


class ActiveLimit(enum.IntEnum):
    """The power limit that cut the q-current window the most."""

    None_ = 0
    Regen = 1
    BusCurrentMotoring = 2
    BusCurrentRegen = 3
    PowerMotoring = 4
    PowerRegen = 5
    WindingTemperature = 6
    StageTemperature = 7
    MissingSensor = 8
    InvalidModel = 9


class Calibration(enum.IntEnum):
    """Calibration routines."""

    offsets = 0
    identification = 1
    alignment = 2
    #: The anticogging map (design §32).
    anticogging = 3
    #: The angle sensor's correction (design §33).
    encoder_linearisation = 4


class TimeoutReaction(enum.IntEnum):
    """Link-watchdog reactions."""

    disable = 0
    stop = 1
    hold = 2


class HomingFailure(enum.IntEnum):
    """Why homing failed (the ``Homing`` reply's ``reason``)."""

    NoStop = 1
    Interrupted = 2
    Aborted = 3
    Refused = 4


class ConfigSource(enum.IntEnum):
    """Which configuration record ``ReadConfig`` reads."""

    live = 0
    stored = 1


class StoreOp(enum.IntEnum):
    """``Store`` operations."""

    save = 0
    load = 1
    erase = 2
    apply = 3
    apply_and_save = 4


class ParamId(enum.IntEnum):
    """Readable parameters; :data:`PARAM_NAMES` has their ``foc-ctl`` names."""

    PolePairs = 0
    ResistanceOhm = 1
    LdH = 2
    LqH = 3
    FluxLinkageWb = 4
    PwmFrequencyHz = 5
    SpeedDivider = 6
    PositionDivider = 7
    FirmwareVersion = 8
    ProtocolVersion = 9
    BusVoltageV = 10
    Calibrated = 11
    MaxLoopCycles = 12
    TelemetryDivider = 13
    WatchdogTimeout = 14
    # Protocol version 4:
    CurrentKp = 15
    CurrentKi = 16
    SpeedKp = 17
    SpeedKi = 18
    PositionKp = 19
    ScopeCapacity = 20
    AngleSource = 21
    CalibrationStep = 22
    CalibrationResult = 23
    BoardMaxCurrentA = 24
    # The command limits in force (rotor frame; the joint's travel range
    # replaces the position range where set):
    MaxCurrentA = 25
    MaxVelocityRadS = 26
    MinPositionRad = 27
    MaxPositionRad = 28
    MaxOpenLoopVoltageV = 29
    MaxOpenLoopOmegaERadS = 30
    MaxImpedanceKp = 31
    MaxImpedanceKd = 32
    # The d-current reference (design §30), writable (``SetParam``):
    FieldWeakening = 33
    Mtpa = 34
    MaxIdA = 35
    ShortCircuit = 36
    # The tables kept with the configuration (design §32, §33): their
    # switches, writable, and their peaks.
    Anticogging = 37
    EncoderLinearisation = 38
    AnticoggingPeakA = 39
    EncoderCorrectionPeakRad = 40


#: Parameter names as ``foc-ctl param NAME`` spells them.
PARAM_NAMES: Dict[ParamId, str] = {
    ParamId.PolePairs: "pole-pairs",
    ParamId.ResistanceOhm: "r",
    ParamId.LdH: "ld",
    ParamId.LqH: "lq",
    ParamId.FluxLinkageWb: "psi",
    ParamId.PwmFrequencyHz: "pwm-frequency",
    ParamId.SpeedDivider: "speed-divider",
    ParamId.PositionDivider: "position-divider",
    ParamId.FirmwareVersion: "firmware-version",
    ParamId.ProtocolVersion: "protocol-version",
    ParamId.BusVoltageV: "bus-voltage",
    ParamId.Calibrated: "calibrated",
    ParamId.MaxLoopCycles: "max-loop-cycles",
    ParamId.TelemetryDivider: "telemetry-divider",
    ParamId.WatchdogTimeout: "watchdog-timeout",
    ParamId.CurrentKp: "current-kp",
    ParamId.CurrentKi: "current-ki",
    ParamId.SpeedKp: "speed-kp",
    ParamId.SpeedKi: "speed-ki",
    ParamId.PositionKp: "position-kp",
    ParamId.ScopeCapacity: "scope-capacity",
    ParamId.AngleSource: "angle-source",
    ParamId.CalibrationStep: "calibration-step",
    ParamId.CalibrationResult: "calibration-result",
    ParamId.BoardMaxCurrentA: "board-max-current",
    ParamId.MaxCurrentA: "max-current",
    ParamId.MaxVelocityRadS: "max-velocity",
    ParamId.MinPositionRad: "min-position",
    ParamId.MaxPositionRad: "max-position",
    ParamId.MaxOpenLoopVoltageV: "max-open-loop-voltage",
    ParamId.MaxOpenLoopOmegaERadS: "max-open-loop-omega-e",
    ParamId.MaxImpedanceKp: "max-impedance-kp",
    ParamId.MaxImpedanceKd: "max-impedance-kd",
    ParamId.FieldWeakening: "field-weakening",
    ParamId.Mtpa: "mtpa",
    ParamId.MaxIdA: "max-id",
    ParamId.ShortCircuit: "short-circuit",
    ParamId.Anticogging: "anticogging",
    ParamId.EncoderLinearisation: "encoder-linearisation",
    ParamId.AnticoggingPeakA: "anticogging-peak",
    ParamId.EncoderCorrectionPeakRad: "encoder-correction-peak",
}

#: Each parameter's unit ("" for a count or a code), as ``foc-ctl param``
#: prints it.
PARAM_UNITS: Dict[ParamId, str] = {
    ParamId.ResistanceOhm: "ohm",
    ParamId.LdH: "H",
    ParamId.LqH: "H",
    ParamId.FluxLinkageWb: "Wb",
    ParamId.PwmFrequencyHz: "Hz",
    ParamId.SpeedDivider: "periods",
    ParamId.PositionDivider: "periods",
    ParamId.BusVoltageV: "V",
    ParamId.MaxLoopCycles: "CPU cycles",
    ParamId.TelemetryDivider: "periods",
    ParamId.WatchdogTimeout: "periods",
    ParamId.CurrentKp: "V/A",
    ParamId.CurrentKi: "V/(A s)",
    ParamId.SpeedKp: "A/(rad/s)",
    ParamId.SpeedKi: "A/rad",
    ParamId.PositionKp: "1/s",
    ParamId.ScopeCapacity: "values",
    ParamId.BoardMaxCurrentA: "A",
    ParamId.MaxCurrentA: "A",
    ParamId.MaxVelocityRadS: "rad/s",
    ParamId.MinPositionRad: "rad",
    ParamId.MaxPositionRad: "rad",
    ParamId.MaxOpenLoopVoltageV: "V",
    ParamId.MaxOpenLoopOmegaERadS: "rad/s",
    ParamId.MaxImpedanceKp: "N m/rad",
    ParamId.MaxImpedanceKd: "N m s/rad",
    ParamId.MaxIdA: "A",
    ParamId.AnticoggingPeakA: "A",
    ParamId.EncoderCorrectionPeakRad: "rad",
}

#: The parameters ``SetParam`` writes (the d-current reference's, design
#: §30; the tables' switches, design §32, §33; only while disabled), each
#: with whether it is an on/off switch (0 or 1).
WRITABLE_PARAMS: Dict[ParamId, bool] = {
    ParamId.FieldWeakening: True,
    ParamId.Mtpa: True,
    ParamId.MaxIdA: False,
    ParamId.ShortCircuit: True,
    ParamId.Anticogging: True,
    ParamId.EncoderLinearisation: True,
}

#: What a writable parameter takes (the device checks the same: a switch
#: 0 or 1; ``max-id`` finite, >= 0, below 1e6 [A]).
PARAM_RANGES: Dict[ParamId, str] = {
    ParamId.FieldWeakening: "0 (off) or 1 (on)",
    ParamId.Mtpa: "0 (off) or 1 (on)",
    ParamId.MaxIdA: "0 .. 1e6 A, finite (field weakening uses at most the current limit)",
    ParamId.ShortCircuit: "0 (off) or 1 (on)",
    ParamId.Anticogging: "0 (off) or 1 (on)",
    ParamId.EncoderLinearisation: "0 (off) or 1 (on)",
}

#: The drive's refusals of a table's switch or a sweep calibration (design
#: §32, §33), by (parameter or routine, error code), in words.
TABLE_REFUSALS: Dict[tuple, str] = {
    (ParamId.Anticogging, ErrorCode.NotCalibrated): (
        "the drive holds no anticogging map: measure one with calibrate_cogging() "
        "(or load a configuration that has one)"
    ),
    (ParamId.EncoderLinearisation, ErrorCode.NotCalibrated): (
        "the drive holds no angle correction: learn one with calibrate_encoder() "
        "(or load a configuration that has one)"
    ),
    (Calibration.anticogging, ErrorCode.NotCalibrated): (
        "the anticogging calibration runs on the closed loop and the drive is not "
        "calibrated: identify it first"
    ),
    (Calibration.encoder_linearisation, ErrorCode.NotCalibrated): (
        "encoder linearisation runs on the closed loop and the drive is not "
        "calibrated: identify it first"
    ),
    (Calibration.anticogging, ErrorCode.Unsupported): (
        "the anticogging calibration needs the rotor's angle at low speed: refused on "
        "halls (their half-count uncertainty, 30 deg electrical, is as wide as a "
        "cogging cycle) and sensorless without injection"
    ),
    (Calibration.encoder_linearisation, ErrorCode.Unsupported): (
        "encoder linearisation learns the angle sensor's own error, so it needs a fine "
        "sensor that is read: refused on halls (interpolated between their edges) and "
        "while the drive runs sensorless"
    ),
}

#: Why the drive refuses field weakening its values allow (``Unsupported``):
#: foc-core's rule (``foc_core::drive::check_field``).
FIELD_WEAKENING_REFUSED = (
    "field weakening needs a fine angle sensor (a coarse one's, halls', half-count "
    "uncertainty turns the weakening d current into q current), max-id above 0, "
    "a field-weakening bandwidth above 0 and a voltage margin of at least 0.02"
)

#: ``calibration-step`` codes (the step running, or where the last run
#: ended).
CALIBRATION_STEPS = (
    "none",
    "current offsets",
    "resistance",
    "inductance",
    "current-loop gains",
    "sensor alignment",
    "flux linkage",
    "mechanics",
    "finished",
    "sensor check",
    "anticogging",
    "encoder linearisation",
    "index search",
)

#: ``calibration-result`` codes below :data:`CALIBRATION_FAILED_BASE`.
CALIBRATION_RESULTS = (
    "none since reset",
    "running",
    "done",
    "aborted (a fault, or a Disable)",
    "offsets rejected (or the current sensor did not answer)",
    "the angle sensor did not answer its check",
)

#: A failure's ``calibration-result`` is this plus the reason's index in
#: :data:`CALIBRATION_FAILURES`.
CALIBRATION_FAILED_BASE = 32

#: Why an identification failed (the drive's ``CalError``).
CALIBRATION_FAILURES = (
    "InvalidInput",
    "InvalidConfig",
    "OverCurrent",
    "Timeout",
    "OpenPhase(A)",
    "OpenPhase(B)",
    "OpenPhase(C)",
    "VoltageLimitReached",
    "PhaseImbalance",
    "CurrentSenseMismatch",
    "NoCurrentResponse",
    "PolePairMismatch",
    "SensorReversed",
    "RotorStuck",
    "SensorNoMotion",
    "SpeedNotReached",
    "ImplausibleResult",
    "NoAcceleration",
    "InertiaOutOfRange",
    "FrictionOutOfRange",
    "MechanicsIllConditioned",
    "IndexNotFound",
)


def calibration_result_text(code: int) -> str:
    """Words for a ``calibration-result`` code."""
    if 0 <= code < len(CALIBRATION_RESULTS):
        return CALIBRATION_RESULTS[code]
    n = code - CALIBRATION_FAILED_BASE
    if 0 <= n < len(CALIBRATION_FAILURES):
        return "failed: " + CALIBRATION_FAILURES[n]
    return "unknown"

PARAM_BY_NAME: Dict[str, ParamId] = {v: k for k, v in PARAM_NAMES.items()}


class ScopeSignal(enum.IntEnum):
    """Scope signal ids (velocity and position in the rotor frame)."""

    id_a = 0
    iq_a = 1
    id_ref_a = 2
    iq_ref_a = 3
    vd_v = 4
    vq_v = 5
    velocity_rad_s = 6
    position_rad = 7
    v_bus_v = 8
    duty_a = 9
    duty_b = 10
    duty_c = 11
    theta_e_rad = 12
    target = 13
    mode = 14


class ScopeTrigger(enum.IntEnum):
    """Scope trigger kinds."""

    manual = 0
    command = 1
    fault = 2
    rising = 3
    falling = 4
    either = 5


class ScopeState(enum.IntEnum):
    """Where a scope capture stands."""

    idle = 0
    armed = 1
    triggered = 2
    done = 3


#: Field names of each request body (what an OutOfRange Nack's field points at).
REQUEST_FIELDS: Dict[int, Tuple[str, ...]] = {
    Tag.SET_LIMITS: (
        "max_current_a",
        "max_velocity_rad_s",
        "min_position_rad",
        "max_position_rad",
        "max_open_loop_voltage_v",
        "max_open_loop_omega_e_rad_s",
        "max_kp_nm_per_rad",
        "max_kd_nm_s_per_rad",
    ),
    Tag.SET_CURRENT_GAINS: ("kp_d", "ki_d", "kp_q", "ki_q"),
    Tag.SET_SPEED_GAINS: ("kp_a_per_rad_s", "ki_a_per_rad"),
    Tag.SET_POSITION_GAINS: ("kp_per_s", "max_velocity_rad_s", "max_acceleration_rad_s2"),
    Tag.SET_DIVIDERS: ("speed", "position"),
    Tag.SET_WATCHDOG: ("timeout_periods", "reaction"),
    Tag.SET_JOINT: (
        "gear_ratio",
        "rotor_at_zero_rad",
        "travel",
        "travel_min_rad",
        "travel_max_rad",
        "fault_margin_rad",
        "brake_accel_rad_s2",
        "kv_a_per_rad_s",
        "entry_blend_periods",
        "timeout_kd_nm_s_per_rad",
    ),
    Tag.RUN_CALIBRATION: ("routine",),
    Tag.READ_PARAM: ("id",),
    Tag.SET_PARAM: ("id", "value"),
    Tag.START_HOMING: (
        "method",
        "home_output_rad",
        "velocity_rad_s",
        "current_a",
        "detect_fraction",
        "confirm_s",
        "backoff_rad",
        "max_travel_rad",
    ),
    Tag.START_TELEMETRY: ("kind", "value"),
    Tag.READ_CONFIG: ("source", "offset"),
    Tag.WRITE_CONFIG: ("offset", "total", "len"),
    Tag.STORE: ("op",),
    Tag.SET_SCOPE: tuple(f"signal{i}" for i in range(SCOPE_SLOTS))
    + ("divider", "samples", "pre_trigger", "trigger", "trigger_signal", "level"),
    Tag.READ_SCOPE_DATA: ("offset",),
}

#: Field names of ``SetCommand`` per mode.
COMMAND_FIELDS: Dict[Mode, Tuple[str, ...]] = {
    Mode.Disabled: ("mode",),
    Mode.Torque: ("mode", "iq_a"),
    Mode.Velocity: ("mode", "rad_s"),
    Mode.Position: ("mode", "rad"),
    Mode.OpenLoop: ("mode", "v_d_v", "v_q_v", "theta_e", "omega_e_rad_s"),
    Mode.Impedance: (
        "mode",
        "position_rad",
        "velocity_rad_s",
        "kp_nm_per_rad",
        "kd_nm_s_per_rad",
        "torque_ff_nm",
        "torque_limit_nm",
    ),
}


def field_name(tag: int, body: bytes, field: int) -> Optional[str]:
    """The name of field ``field`` of the request ``tag`` with ``body``."""
    if tag == Tag.SET_COMMAND:
        try:
            names = COMMAND_FIELDS[Mode(body[0])]
        except (IndexError, ValueError):
            return None
    else:
        names = REQUEST_FIELDS.get(tag, ())
    return names[field] if 0 <= field < len(names) else None


#: Requests whose bodies are f32 fields only.
_F32_REQUESTS = (Tag.SET_LIMITS, Tag.SET_CURRENT_GAINS, Tag.SET_SPEED_GAINS, Tag.SET_POSITION_GAINS)


def field_value(tag: int, body: bytes, field: int) -> Optional[float]:
    """The value of field ``field`` of request ``tag`` as sent in ``body``
    (``None`` where it is not a number: a mode, a choice)."""
    try:
        if tag == Tag.SET_COMMAND:
            if field < 1:
                return None
            off = 1 + 4 * (field - 1)
            if body[0] == Mode.OpenLoop and field == 3:
                return struct.unpack_from("<I", body, off)[0] / 2.0**32  # turns
            return struct.unpack_from("<f", body, off)[0]
        if tag in _F32_REQUESTS:
            return struct.unpack_from("<f", body, 4 * field)[0]
        if tag == Tag.SET_DIVIDERS:
            return float(struct.unpack_from("<H", body, 2 * field)[0])
        if tag == Tag.SET_WATCHDOG and field == 0:
            return float(struct.unpack_from("<I", body, 0)[0])
        if tag == Tag.SET_PARAM:
            return float(body[0]) if field == 0 else struct.unpack_from("<f", body, 1)[0]
    except (struct.error, IndexError):
        return None
    return None


def range_params(tag: int, body: bytes, field: int) -> Optional[tuple]:
    """For a command's out-of-range field: ``(low, high, what)`` where
    ``low`` and ``high`` are :class:`ParamId` s to read (or a number), the
    limits in force that field is checked against; ``None`` otherwise."""
    if tag != Tag.SET_COMMAND or not body:
        return None
    mode = body[0]
    table = {
        (Mode.Torque, 1): (-1, ParamId.MaxCurrentA, "the current limit"),
        (Mode.Velocity, 1): (-1, ParamId.MaxVelocityRadS, "the velocity limit, rotor"),
        (Mode.Position, 1): (ParamId.MinPositionRad, ParamId.MaxPositionRad, "the position range, rotor"),
        (Mode.OpenLoop, 1): (-1, ParamId.MaxOpenLoopVoltageV, "the open-loop voltage limit"),
        (Mode.OpenLoop, 2): (-1, ParamId.MaxOpenLoopVoltageV, "the open-loop voltage limit"),
        (Mode.OpenLoop, 4): (-1, ParamId.MaxOpenLoopOmegaERadS, "the open-loop speed limit, electrical"),
        (Mode.Impedance, 3): (0.0, ParamId.MaxImpedanceKp, "the stiffness limit, rotor"),
        (Mode.Impedance, 4): (0.0, ParamId.MaxImpedanceKd, "the damping limit, rotor"),
    }
    return table.get((mode, field))


# ---------------------------------------------------------------- requests


def f32_bits(x: float) -> bytes:
    """``x`` as a little-endian f32 (out-of-range magnitudes become +-inf)."""
    try:
        return struct.pack("<f", x)
    except OverflowError:
        return struct.pack("<f", math.copysign(math.inf, x))


def pack_f32s(*xs: float) -> bytes:
    """Several f32 fields."""
    return b"".join(f32_bits(x) for x in xs)


def body_command(mode: Mode, *values: float) -> bytes:
    """``SetCommand`` body for the modes with f32 fields only."""
    return bytes([mode]) + pack_f32s(*values)


def body_open_loop(v_d_v: float, v_q_v: float, theta_e_bits: int, omega_e_rad_s: float) -> bytes:
    """``SetCommand`` open-loop body (``theta_e`` in turn/2^32)."""
    return (
        bytes([Mode.OpenLoop])
        + pack_f32s(v_d_v, v_q_v)
        + struct.pack("<I", theta_e_bits)
        + f32_bits(omega_e_rad_s)
    )


def body_limits(
    max_current_a: float,
    max_velocity_rad_s: float,
    min_position_rad: float,
    max_position_rad: float,
    max_open_loop_voltage_v: float,
    max_open_loop_omega_e_rad_s: float,
    max_kp_nm_per_rad: float,
    max_kd_nm_s_per_rad: float,
) -> bytes:
    """``SetLimits`` body (rotor frame)."""
    return pack_f32s(
        max_current_a,
        max_velocity_rad_s,
        min_position_rad,
        max_position_rad,
        max_open_loop_voltage_v,
        max_open_loop_omega_e_rad_s,
        max_kp_nm_per_rad,
        max_kd_nm_s_per_rad,
    )


def body_current_gains(kp_d: float, ki_d: float, kp_q: float, ki_q: float) -> bytes:
    """``SetCurrentGains`` body."""
    return pack_f32s(kp_d, ki_d, kp_q, ki_q)


def body_speed_gains(kp_a_per_rad_s: float, ki_a_per_rad: float) -> bytes:
    """``SetSpeedGains`` body (rotor frame)."""
    return pack_f32s(kp_a_per_rad_s, ki_a_per_rad)


def body_position_gains(
    kp_per_s: float, max_velocity_rad_s: float, max_acceleration_rad_s2: float
) -> bytes:
    """``SetPositionGains`` body (rotor frame)."""
    return pack_f32s(kp_per_s, max_velocity_rad_s, max_acceleration_rad_s2)


def body_dividers(speed: int, position: int) -> bytes:
    """``SetDividers`` body."""
    return struct.pack("<HH", speed, position)


def body_watchdog(timeout_periods: int, reaction: int) -> bytes:
    """``SetWatchdog`` body (``reaction`` a :class:`TimeoutReaction` code)."""
    return struct.pack("<IB", timeout_periods, reaction)


def body_calibration(routine: int) -> bytes:
    """``RunCalibration`` body (a :class:`Calibration` code)."""
    return bytes([routine])


def body_read_param(pid: int) -> bytes:
    """``ReadParam`` body (a :class:`ParamId` code)."""
    return bytes([pid])


def body_set_param(pid: int, value: float) -> bytes:
    """``SetParam`` body (a writable :class:`ParamId` code, its value)."""
    return bytes([pid]) + f32_bits(value)


def body_start_telemetry(
    rate_hz: Optional[float] = None, *, every_periods: Optional[int] = None
) -> bytes:
    """``StartTelemetry`` body: a rate [Hz] or every K periods (exactly one)."""
    if (rate_hz is None) == (every_periods is None):
        raise ValueError("give exactly one of rate_hz and every_periods")
    if rate_hz is not None:
        return b"\x01" + f32_bits(rate_hz)
    return b"\x00" + struct.pack("<I", every_periods)


def body_read_config(source: int, offset: int) -> bytes:
    """``ReadConfig`` body (``source`` a :class:`ConfigSource` code)."""
    return struct.pack("<BH", source, offset)


def body_store(op: int) -> bytes:
    """``Store`` body (a :class:`StoreOp` code)."""
    return bytes([op])


def body_read_scope_data(offset: int) -> bytes:
    """``ReadScopeData`` body (value index)."""
    return struct.pack("<H", offset)


@dataclass(frozen=True)
class EndStop:
    """End-stop search settings of ``StartHoming`` (velocity, back-off and
    longest travel in the output frame; the velocity's sign is the
    direction)."""

    velocity_rad_s: float
    current_a: float
    detect_fraction: float
    confirm_s: float
    backoff_rad: float
    max_travel_rad: float


def body_homing(home_output_rad: float, end_stop: Optional[EndStop] = None) -> bytes:
    """``StartHoming`` body: the present position is home (``end_stop``
    None), or search an end stop; the home point reads ``home_output_rad``
    [rad, output]."""
    if end_stop is None:
        return b"\x00" + f32_bits(home_output_rad)
    e = end_stop
    return b"\x01" + pack_f32s(
        home_output_rad,
        e.velocity_rad_s,
        e.current_a,
        e.detect_fraction,
        e.confirm_s,
        e.backoff_rad,
        e.max_travel_rad,
    )


def body_joint(j: "JointSettings") -> bytes:
    """``SetJoint`` body."""
    if j.travel_out_rad is None:
        flag, lo, hi = 0, 0.0, 0.0
    else:
        flag, (lo, hi) = 1, j.travel_out_rad
    return (
        pack_f32s(j.gear_ratio, j.rotor_at_zero_rad)
        + bytes([flag])
        + pack_f32s(lo, hi, j.fault_margin_rad, j.brake_accel_rad_s2, j.kv_a_per_rad_s)
        + struct.pack("<I", j.entry_blend_periods)
        + f32_bits(j.timeout_kd_nm_s_per_rad)
    )


def body_scope(
    signals: Sequence[int],
    divider: int,
    samples: int,
    pre_trigger: int,
    trigger: int,
    trigger_signal: int,
    level: float,
) -> bytes:
    """``SetScope`` body (``signals`` padded with 0xFF to 8 slots)."""
    slots = list(signals) + [SCOPE_UNUSED] * (SCOPE_SLOTS - len(signals))
    return (
        bytes(slots)
        + struct.pack("<HHHBB", divider, samples, pre_trigger, trigger, trigger_signal)
        + f32_bits(level)
    )


def body_chunk(offset: int, total: int, data: bytes) -> bytes:
    """A configuration chunk (``WriteConfig`` body)."""
    return struct.pack("<HHB", offset, total, len(data)) + bytes(data)


# ----------------------------------------------------------------- replies


class _Reader:
    def __init__(self, tag: int, body: bytes) -> None:
        self.tag = tag
        self.body = body
        self.pos = 0

    def take(self, fmt: str) -> tuple:
        n = struct.calcsize(fmt)
        if self.pos + n > len(self.body):
            raise ProtocolError(
                f"reply 0x{self.tag:02x}: body too short ({len(self.body)} bytes)"
            )
        v = struct.unpack_from(fmt, self.body, self.pos)
        self.pos += n
        return v

    def bytes(self, n: int) -> bytes:
        if self.pos + n > len(self.body):
            raise ProtocolError(f"reply 0x{self.tag:02x}: body too short ({len(self.body)} bytes)")
        v = self.body[self.pos : self.pos + n]
        self.pos += n
        return bytes(v)

    def finish(self) -> None:
        if self.pos != len(self.body):
            raise ProtocolError(
                f"reply 0x{self.tag:02x}: body too long ({len(self.body)} bytes, "
                f"{self.pos} expected)"
            )


def _enum(cls, code: int, what: str):
    try:
        return cls(code)
    except ValueError:
        raise ProtocolError(f"{what}: unknown code {code}") from None


@dataclass(frozen=True)
class Hello:
    """Reply to ``Ping``."""

    protocol_version: int
    firmware_version: Tuple[int, int, int]
    max_payload: int

    @property
    def firmware(self) -> str:
        """Firmware version as ``"major.minor.patch"``."""
        return ".".join(str(v) for v in self.firmware_version)


def decode_hello(body: bytes) -> Hello:
    r = _Reader(Tag.HELLO, body)
    pv, a, b, c, mp = r.take("<5B")
    r.finish()
    return Hello(pv, (a, b, c), mp)


@dataclass(frozen=True)
class FaultReport:
    """Latched faults."""

    bits: int
    first_code: int

    @property
    def codes(self) -> List[int]:
        """Codes of every latched fault."""
        return [n for n in range(32) if self.bits >> n & 1]

    @property
    def faults(self) -> List[object]:
        """Every latched fault (a :class:`Fault`, or the code when unknown)."""
        out: List[object] = []
        for n in self.codes:
            try:
                out.append(Fault(n))
            except ValueError:
                out.append(n)
        return out

    @property
    def first(self) -> Optional[object]:
        """The first fault (None when nothing is latched)."""
        if self.first_code == 0:
            return None
        try:
            return Fault(self.first_code)
        except ValueError:
            return self.first_code

    def __bool__(self) -> bool:
        return self.bits != 0


def decode_faults(body: bytes) -> FaultReport:
    r = _Reader(Tag.FAULTS, body)
    bits, first = r.take("<IB")
    r.finish()
    return FaultReport(bits, first)


def decode_param(body: bytes) -> Tuple[int, float]:
    r = _Reader(Tag.PARAM, body)
    pid, value = r.take("<Bf")
    r.finish()
    return pid, value


NO_TEMPERATURE = -32768

#: Telemetry fields in wire order, with the struct format of each.
TELEMETRY_LAYOUT: Tuple[Tuple[str, str], ...] = (
    ("period", "I"),
    ("i_d_a", "f"),
    ("i_q_a", "f"),
    ("v_d_v", "f"),
    ("v_q_v", "f"),
    ("velocity_rad_s", "f"),
    ("position_rad", "f"),
    ("mode", "B"),
    ("fault_code", "B"),
    ("max_loop_cycles", "I"),
    ("v_bus_v", "f"),
    ("power_limit", "B"),
    ("limit_left_pct", "B"),
    ("flags", "B"),
    ("winding_dC", "h"),
    ("stage_dC", "h"),
)
TELEMETRY_FORMAT = "<" + "".join(f for _, f in TELEMETRY_LAYOUT)
TELEMETRY_BYTES = struct.calcsize(TELEMETRY_FORMAT)


@dataclass(frozen=True)
class Telemetry:
    """One telemetry sample (velocity and position in the output frame)."""

    period: int
    """Current-loop period counter (wraps at 2^32)."""
    i_d_a: float
    i_q_a: float
    v_d_v: float
    v_q_v: float
    velocity_rad_s: float
    position_rad: float
    mode: int
    """A :class:`Mode` code."""
    fault_code: int
    """First latched fault code (0: none)."""
    max_loop_cycles: int
    v_bus_v: float
    power_limit: int
    """An :class:`ActiveLimit` code."""
    limit_left_pct: int
    brake_on: bool
    brake_locked: bool
    winding_c: float
    """Estimated winding temperature [deg C] (NaN: none)."""
    stage_c: float
    """Power-stage temperature [deg C] (NaN: none)."""
    angle_in_use: int = 0
    """An :class:`AngleInUse` code: where the current loop's angle came from
    (0 before protocol version 5)."""

    @property
    def mode_name(self) -> str:
        """The mode's name."""
        return Mode(self.mode).name


#: Numeric telemetry fields (what :meth:`foc_drive.Drive.stream` returns arrays of).
TELEMETRY_FIELDS: Tuple[str, ...] = tuple(Telemetry.__dataclass_fields__)


def _temperature(w: int) -> float:
    return math.nan if w == NO_TEMPERATURE else w / 10.0


def decode_telemetry(body: bytes, tag: int = Tag.TELEMETRY) -> Telemetry:
    """A ``Telemetry`` or ``Stream`` body."""
    if len(body) != TELEMETRY_BYTES:
        raise ProtocolError(
            f"reply 0x{tag:02x}: telemetry body of {len(body)} bytes ({TELEMETRY_BYTES} expected)"
        )
    v = struct.unpack(TELEMETRY_FORMAT, body)
    d = dict(zip((n for n, _ in TELEMETRY_LAYOUT), v))
    _enum(Mode, d["mode"], "telemetry mode")
    _enum(ActiveLimit, d["power_limit"], "telemetry power limit")
    if d["limit_left_pct"] > 100:
        raise ProtocolError(f"telemetry limit_left_pct {d['limit_left_pct']} > 100")
    flags = d.pop("flags")
    if flags > 15:
        raise ProtocolError(f"telemetry flags 0x{flags:02x}")
    return Telemetry(
        period=d["period"],
        i_d_a=d["i_d_a"],
        i_q_a=d["i_q_a"],
        v_d_v=d["v_d_v"],
        v_q_v=d["v_q_v"],
        velocity_rad_s=d["velocity_rad_s"],
        position_rad=d["position_rad"],
        mode=d["mode"],
        fault_code=d["fault_code"],
        max_loop_cycles=d["max_loop_cycles"],
        v_bus_v=d["v_bus_v"],
        power_limit=d["power_limit"],
        limit_left_pct=d["limit_left_pct"],
        brake_on=bool(flags & 1),
        brake_locked=bool(flags & 2),
        winding_c=_temperature(d["winding_dC"]),
        stage_c=_temperature(d["stage_dC"]),
        angle_in_use=(flags >> 2) & 3,
    )


@dataclass(frozen=True)
class ConfigChunk:
    """A piece of a configuration record."""

    offset: int
    total: int
    data: bytes


def decode_chunk(body: bytes) -> ConfigChunk:
    r = _Reader(Tag.CONFIG_CHUNK, body)
    offset, total, n = r.take("<HHB")
    if n > CHUNK_BYTES:
        raise ProtocolError(f"config chunk of {n} bytes (at most {CHUNK_BYTES})")
    data = r.bytes(n)
    r.finish()
    return ConfigChunk(offset, total, data)


@dataclass(frozen=True)
class JointSettings:
    """A joint's settings (``SetJoint``, the ``Joint`` reply)."""

    gear_ratio: float = 1.0
    """Rotor turns per output turn, signed."""
    rotor_at_zero_rad: float = 0.0
    """Rotor position where the output reads 0 [rad, rotor]."""
    travel_out_rad: Optional[Tuple[float, float]] = None
    """Travel range (min, max) [rad, output]; None: none."""
    fault_margin_rad: float = 0.0
    brake_accel_rad_s2: float = 0.0
    kv_a_per_rad_s: float = 0.0
    entry_blend_periods: int = 0
    timeout_kd_nm_s_per_rad: float = 0.0


def decode_joint(body: bytes) -> JointSettings:
    r = _Reader(Tag.JOINT, body)
    g, z, flag, lo, hi, fm, ba, kv, eb, tkd = r.take("<ffBfffffIf")
    r.finish()
    if flag == 0:
        # Without a travel range its two fields are +0.0 (one layout per value).
        if struct.pack("<ff", lo, hi) != bytes(8):
            raise ProtocolError(f"joint without travel but with a range ({lo}, {hi})")
        travel = None
    elif flag == 1:
        travel = (lo, hi)
    else:
        raise ProtocolError(f"joint travel flag {flag}")
    return JointSettings(g, z, travel, fm, ba, kv, eb, tkd)


@dataclass(frozen=True)
class Homing:
    """Where homing stands: ``state`` 0 idle, 1 running, 2 done, 3 failed."""

    state: int
    reason: int

    STATES = ("idle", "running", "done", "failed")

    @property
    def state_name(self) -> str:
        return self.STATES[self.state] if self.state < 4 else str(self.state)

    @property
    def failure(self) -> Optional[HomingFailure]:
        """Why homing failed (None unless failed)."""
        return HomingFailure(self.reason) if self.state == 3 else None


def decode_homing(body: bytes) -> Homing:
    """A ``Homing`` body: ``reason`` is a :class:`HomingFailure` code when
    failed, else 0."""
    r = _Reader(Tag.HOMING, body)
    s, reason = r.take("<BB")
    r.finish()
    if s > 3:
        raise ProtocolError(f"homing state {s}")
    if s == 3:
        _enum(HomingFailure, reason, "homing failure")
    elif reason != 0:
        raise ProtocolError(f"homing state {s} with reason {reason}")
    return Homing(s, reason)


@dataclass(frozen=True)
class ScopeStatus:
    """The scope's configuration and state (``Scope`` reply)."""

    state: ScopeState
    signals: Tuple[int, ...]
    """Used signal ids, in slot order."""
    divider: int
    samples: int
    pre_trigger: int
    trigger: int
    trigger_signal: int
    level: float
    captured: int
    """Samples per channel available."""
    trigger_index: int
    """The trigger's sample index within the readout."""
    trigger_period: int
    """PWM period counter at the trigger."""
    sample_period_s: float
    capacity: int
    """Values the buffer holds in all."""

    @property
    def signal_names(self) -> List[str]:
        """Names of the used signals (the id as text when unknown)."""
        return [signal_name(s) for s in self.signals]

    @property
    def done(self) -> bool:
        return self.state == ScopeState.done


SCOPE_FORMAT = "<B8BHHHBBfHHIfH"
SCOPE_BYTES = struct.calcsize(SCOPE_FORMAT)


def decode_scope(body: bytes) -> ScopeStatus:
    if len(body) != SCOPE_BYTES:
        raise ProtocolError(f"scope reply of {len(body)} bytes ({SCOPE_BYTES} expected)")
    v = struct.unpack(SCOPE_FORMAT, body)
    state = _enum(ScopeState, v[0], "scope state")
    slots = v[1:9]
    used = tuple(s for s in slots if s != SCOPE_UNUSED)
    if any(s == SCOPE_UNUSED for s in slots[: len(used)]):
        raise ProtocolError(f"scope signals not packed: {slots}")
    (divider, samples, pre, trig, trig_sig, level, captured, tidx, tper, sp, cap) = v[9:]
    return ScopeStatus(
        state, used, divider, samples, pre, trig, trig_sig, level, captured, tidx, tper, sp, cap
    )


def decode_scope_data(body: bytes) -> Tuple[int, Tuple[float, ...]]:
    """``ScopeData``: (offset, values)."""
    r = _Reader(Tag.SCOPE_DATA, body)
    offset, count = r.take("<HB")
    if count > SCOPE_DATA_MAX:
        raise ProtocolError(f"scope data of {count} values (at most {SCOPE_DATA_MAX})")
    values = r.take(f"<{count}f") if count else ()
    r.finish()
    return offset, tuple(values)


def decode_nack(body: bytes) -> Tuple[int, int]:
    r = _Reader(Tag.NACK, body)
    code, field = r.take("<BB")
    r.finish()
    return code, field


def decode_ack(body: bytes) -> None:
    _Reader(Tag.ACK, body).finish()


def signal_name(sid: int) -> str:
    """A scope signal id's name (the id as text when unknown)."""
    try:
        return ScopeSignal(sid).name
    except ValueError:
        return str(sid)
