"""The :class:`Drive` client: typed requests with timeouts, retransmission
and sequence-number checking, streamed telemetry, configuration records
and the scope.

Mirrors the Rust client (``ctl/src/lib.rs``): hosts never use ``seq`` 0;
every reply echoes its request's ``seq``; a request without a reply in
time is retransmitted as the very same frame (the device answers a repeat
from its reply cache instead of running it twice); a ``seq`` 0 Nack for a
bad CRC or a malformed frame makes it retransmit at once; unsolicited
``Stream`` frames are queued, never taken for a reply.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import numbers
import os
import random
import time
from dataclasses import dataclass
from typing import Any, Callable, Deque, Dict, List, Optional, Sequence, Union

import numpy as np

from . import messages as m
from .codec import FrameDecoder, FrameFault, RawFrame, encode_frame
from .errors import (
    CalibrationError,
    DriveError,
    NackError,
    ProtocolError,
    TimeoutError,
    TransferError,
)
from .messages import (
    ErrorCode,
    FaultReport,
    Hello,
    Homing,
    JointSettings,
    Mode,
    ParamId,
    ScopeStatus,
    Tag,
    Telemetry,
)
from .scope import ScopeCapture, SignalSpec, TriggerSpec, parse_signals, parse_trigger
from .transport import SerialTransport, TcpTransport, Transport

__all__ = ["Drive", "LinkStats", "StreamSample", "StreamData"]

PathLike = Union[str, "os.PathLike[str]"]


@dataclass
class LinkStats:
    """Link counters."""

    requests: int = 0
    """Requests sent (not counting retransmissions)."""
    retransmissions: int = 0
    bad_frames: int = 0
    """Frames that failed to decode on the host."""
    stale_replies: int = 0
    """Replies that matched no outstanding request (late replies)."""
    stream_samples: int = 0
    """Streamed samples received."""
    stream_lost: int = 0
    """Streamed samples lost (gaps in the stream counter)."""


@dataclass(frozen=True)
class StreamSample:
    """A streamed telemetry sample as received."""

    host_time_s: float
    """Host time (``time.monotonic()``) at reception."""
    seq: int
    """The stream counter (wraps at 2^16)."""
    sample: Telemetry


class StreamData(dict):
    """What :meth:`Drive.stream` returns: a ``dict`` of numpy arrays, one
    per :class:`Telemetry` field (``period``, ``i_q_a``, ``velocity_rad_s``
    ...), plus ``seq`` (stream counter), ``host_time_s`` and ``t`` (seconds
    since the first sample, from the period counter and the PWM frequency;
    from the host clock when the frequency is unknown).

    Attributes ``lost`` (samples lost, counted by gaps in the stream
    counter), ``received`` and ``duration_s``.
    """

    lost: int = 0
    received: int = 0
    duration_s: float = 0.0

    def __repr__(self) -> str:
        return (
            f"StreamData({self.received} samples, {self.lost} lost, "
            f"fields {sorted(self)})"
        )


# Telemetry field -> numpy dtype of its array.
_STREAM_DTYPES: Dict[str, Any] = {
    "period": np.uint32,
    "mode": np.uint8,
    "fault_code": np.uint8,
    "max_loop_cycles": np.uint32,
    "power_limit": np.uint8,
    "limit_left_pct": np.uint8,
    "brake_on": np.bool_,
    "brake_locked": np.bool_,
    "angle_in_use": np.uint8,
}

_MAX_QUEUED = 100_000


def _real(name: str, x: object) -> float:
    if isinstance(x, bool) or not isinstance(x, numbers.Real):
        raise TypeError(f"{name} must be a real number, not {type(x).__name__}")
    return float(x)


def _uint(name: str, x: object, bits: int) -> int:
    if isinstance(x, bool) or not isinstance(x, numbers.Integral):
        raise TypeError(f"{name} must be an integer, not {type(x).__name__}")
    v = int(x)
    if not 0 <= v < (1 << bits):
        raise ValueError(f"{name} = {v} does not fit a u{bits}")
    return v


def _choice(name: str, x: object, enum_cls):
    """An enum member from a name, a member or a code."""
    if isinstance(x, enum_cls):
        return x
    if isinstance(x, str):
        try:
            return enum_cls[x.replace("-", "_")]
        except KeyError:
            names = ", ".join(e.name for e in enum_cls)
            raise ValueError(f"unknown {name} {x!r} (one of {names})") from None
    if isinstance(x, numbers.Integral) and not isinstance(x, bool):
        try:
            return enum_cls(int(x))
        except ValueError:
            raise ValueError(f"unknown {name} code {x}") from None
    raise TypeError(f"{name} must be a name or a code, not {type(x).__name__}")


def _table_refusal(tag: int, body: bytes, code: int) -> Optional[str]:
    """The words for the drive's refusal of a table's switch or a sweep
    calibration (design §32, §33), else ``None``."""
    if not body:
        return None
    if tag == Tag.SET_PARAM:
        key: object = ParamId._value2member_map_.get(body[0])
    elif tag == Tag.RUN_CALIBRATION:
        key = m.Calibration._value2member_map_.get(body[0])
    else:
        return None
    return m.TABLE_REFUSALS.get((key, code))


class Drive:
    """A connection to a drive's command channel.

    Create one with :meth:`connect_tcp` or :meth:`open_serial` (or over
    any :class:`~foc_drive.transport.Transport`); use it as a context
    manager or call :meth:`close`. Not thread-safe: use one ``Drive`` per
    thread.

    Units and frames as on the wire: positions, velocities and impedance
    gains of commands and telemetry in the joint's output frame, the
    motor's limits in the rotor frame, currents in A, voltages in V.

    Every request raises :class:`NackError` when the device refuses it
    (nothing changed), :class:`TimeoutError` when no reply came after
    all attempts and :class:`ProtocolError` for a reply of the wrong kind
    or layout.
    """

    def __init__(
        self,
        transport: Transport,
        timeout: float = 1.0,
        retries: int = 3,
        store_timeout: float = 10.0,
    ) -> None:
        """Client over ``transport``: ``timeout`` [s] per attempt,
        ``retries`` retransmissions after the first attempt,
        ``store_timeout`` [s] per attempt for flash operations. Sends one
        0x00 first so the device drops whatever it had half-received."""
        self._transport: Optional[Transport] = transport
        self._decoder = FrameDecoder()
        # A random first sequence number: the device answers a repeated
        # frame (same seq, same CRC) from its cache without running it, so a
        # new connection must not start where the last one did.
        self._seq = random.randrange(0x10000)
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.store_timeout = float(store_timeout)
        self._replies: Deque[RawFrame] = collections.deque()
        self._queue: Deque[StreamSample] = collections.deque(maxlen=_MAX_QUEUED)
        self._last_stream_seq: Optional[int] = None
        self.stats = LinkStats()
        self._hello: Optional[Hello] = None
        transport.write(b"\x00")

    # ------------------------------------------------------------ opening

    @classmethod
    def connect_tcp(
        cls,
        host: str,
        port: int,
        timeout: float = 1.0,
        *,
        retries: int = 3,
        check_version: bool = True,
    ) -> "Drive":
        """Connect over TCP (``foc-ctl simulate``, QEMU's serial port).

        ``timeout`` is the reply timeout per attempt [s]. With
        ``check_version`` the drive is pinged and a protocol version this
        package does not speak raises :class:`ProtocolError`.
        """
        if not isinstance(port, numbers.Integral) or isinstance(port, bool):
            raise TypeError("port must be an integer")
        t = TcpTransport.connect(host, int(port), connect_timeout=max(timeout, 1.0) * 5)
        return cls._opened(t, timeout, retries, check_version)

    @classmethod
    def open_serial(
        cls,
        path: str,
        baud: int = 115200,
        timeout: float = 1.0,
        *,
        retries: int = 3,
        check_version: bool = True,
    ) -> "Drive":
        """Open a serial port (needs pyserial: ``pip install 'foc-drive[serial]'``)."""
        return cls._opened(SerialTransport(path, baud), timeout, retries, check_version)

    @classmethod
    def _opened(cls, t: Transport, timeout: float, retries: int, check: bool) -> "Drive":
        d = cls(t, timeout=timeout, retries=retries)
        if check:
            try:
                h = d.ping()
                if h.protocol_version not in m.SUPPORTED_PROTOCOL_VERSIONS:
                    raise ProtocolError(
                        f"the drive speaks protocol version {h.protocol_version}, "
                        f"this package {m.SUPPORTED_PROTOCOL_VERSIONS}"
                    )
            except BaseException:
                d.close()
                raise
        return d

    def close(self) -> None:
        """Close the connection (idempotent)."""
        if self._transport is not None:
            try:
                self._transport.close()
            finally:
                self._transport = None

    def __enter__(self) -> "Drive":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._transport is None

    # ------------------------------------------------------------ the link

    def _t(self) -> Transport:
        if self._transport is None:
            raise ConnectionError("the drive connection is closed")
        return self._transport

    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        if self._seq == 0:
            self._seq = 1
        return self._seq

    def _queue_stream(self, f: RawFrame) -> None:
        try:
            sample = m.decode_telemetry(f.body, Tag.STREAM)
        except ProtocolError:
            self.stats.bad_frames += 1
            return
        if self._last_stream_seq is not None:
            gap = (f.seq - self._last_stream_seq - 1) & 0xFFFF
            # A huge gap is a restart of the stream, not a loss.
            if gap < 0x8000:
                self.stats.stream_lost += gap
        self._last_stream_seq = f.seq
        self.stats.stream_samples += 1
        self._queue.append(StreamSample(time.monotonic(), f.seq, sample))

    def _pump(self, deadline: float) -> None:
        """One read (waiting at most until ``deadline``): stream frames are
        queued, other frames kept for :meth:`_request`."""
        data = self._t().read(4096, max(deadline - time.monotonic(), 0.0))
        for f in self._decoder.feed(data):
            if isinstance(f, FrameFault):
                self.stats.bad_frames += 1
            elif f.tag == Tag.STREAM:
                self._queue_stream(f)
            else:
                self._replies.append(f)

    def _nack(self, tag: int, body: bytes, reply: RawFrame) -> NackError:
        code, field = m.decode_nack(reply.body)
        try:
            ec: int = ErrorCode(code)
        except ValueError:
            ec = code
        fname = m.field_name(tag, body, field) if ec == ErrorCode.OutOfRange else None
        text = m.ERROR_TEXT.get(ec, f"error code {code}")
        value = m.field_value(tag, body, field) if ec == ErrorCode.OutOfRange else None
        if ec == ErrorCode.OutOfRange:
            shown = f"{fname} = {value:g}" if fname and value is not None else fname
            text = f"field {field}{f' ({shown})' if shown else ''} out of range"
            allowed = self._allowed(tag, body, field)
            if allowed:
                text += f" (allowed: {allowed})"
        elif _table_refusal(tag, body, ec):
            text = _table_refusal(tag, body, ec) or text
        elif ec == ErrorCode.Unsupported and tag == Tag.SET_PARAM and body[:1] == bytes(
            [ParamId.FieldWeakening]
        ):
            text = m.FIELD_WEAKENING_REFUSED
        elif ec == ErrorCode.Unsupported and tag == Tag.SET_PARAM and body[:1] == bytes(
            [ParamId.MaxIdA]
        ):
            text = "max-id 0 is refused while field weakening is on (switch it off first)"
        elif ec == ErrorCode.Unsupported and tag == Tag.SET_LIMITS:
            hw = self._quiet_param(ParamId.BoardMaxCurrentA)
            asked = m.field_value(tag, body, 0)
            if hw is not None and asked is not None and asked > hw:
                text = f"max_current_a = {asked:g} A is above this board's hardware limit of {hw:g} A"
        elif ec == ErrorCode.UnknownMessage and tag >= Tag.SET_SCOPE:
            text += f" (the scope needs protocol version {m.SCOPE_PROTOCOL_VERSION})"
        name = Tag(tag).name if tag in Tag._value2member_map_ else f"0x{tag:02x}"
        return NackError(ec, field, f"{name} refused by the device: {text}; nothing changed", fname, value)

    def _quiet_param(self, pid: ParamId) -> Optional[float]:
        """A parameter, or ``None`` when it cannot be read (an older device)."""
        try:
            return self.param(pid)
        except DriveError:
            return None

    def _allowed(self, tag: int, body: bytes, field: int) -> Optional[str]:
        """The range an out-of-range command field is checked against, read
        from the device's limits in force (``None`` where unknown)."""
        if tag == Tag.SET_PARAM and field == 1 and body:
            return m.PARAM_RANGES.get(body[0])
        r = m.range_params(tag, body, field)
        if r is None:
            return None
        lo_spec, hi_spec, what = r
        hi = self._quiet_param(hi_spec)
        if hi is None:
            return None
        if isinstance(lo_spec, ParamId):
            lo = self._quiet_param(lo_spec)
            if lo is None:
                return None
        else:
            lo = -hi if lo_spec == -1 else float(lo_spec)
        unit = m.PARAM_UNITS.get(hi_spec, "")
        return f"{lo:g} .. {hi:g} {unit}, {what}"


    def request(self, tag: int, body: bytes = b"", timeout: Optional[float] = None) -> RawFrame:
        """Send request ``tag`` with ``body`` and return its reply frame
        (any kind but Nack, which raises :class:`NackError`). Low level:
        the typed methods below are built on it."""
        per_attempt = self.timeout if timeout is None else timeout
        seq = self._next_seq()
        frame = encode_frame(tag, seq, body)
        self.stats.requests += 1
        attempts = self.retries + 1
        for attempt in range(attempts):
            if attempt > 0:
                self.stats.retransmissions += 1
            self._t().write(frame)
            deadline = time.monotonic() + per_attempt
            resend = False
            while not resend:
                while self._replies:
                    r = self._replies.popleft()
                    if r.seq == seq:
                        if r.tag == Tag.NACK:
                            raise self._nack(tag, body, r)
                        return r
                    if r.seq == 0 and r.tag == Tag.NACK:
                        code = r.body[0] if r.body else 0
                        if code in (ErrorCode.BadCrc, ErrorCode.Malformed):
                            # The device could not read our frame: again, now.
                            resend = True
                            break
                    self.stats.stale_replies += 1
                if resend or time.monotonic() >= deadline:
                    break
                self._pump(deadline)
        name = Tag(tag).name if tag in Tag._value2member_map_ else f"0x{tag:02x}"
        raise TimeoutError(f"no reply to {name} after {attempts} attempt(s)")

    def _expect(self, tag: int, body: bytes, reply: int, timeout: Optional[float] = None) -> bytes:
        r = self.request(tag, body, timeout)
        if r.tag != reply:
            raise ProtocolError(
                f"{Tag(tag).name}: reply 0x{r.tag:02x}, expected {Tag(reply).name}"
            )
        return r.body

    def _ack(self, tag: int, body: bytes = b"", timeout: Optional[float] = None) -> None:
        m.decode_ack(self._expect(tag, body, Tag.ACK, timeout))

    def _flash_timeout(self) -> float:
        return max(self.store_timeout, self.timeout)

    # --------------------------------------------------------------- basics

    def ping(self) -> Hello:
        """Protocol and firmware versions (no side effects)."""
        self._hello = m.decode_hello(self._expect(Tag.PING, b"", Tag.HELLO))
        return self._hello

    @property
    def protocol_version(self) -> int:
        """The device's protocol version (pings once, then cached)."""
        if self._hello is None:
            self.ping()
        assert self._hello is not None
        return self._hello.protocol_version

    def keep_alive(self) -> None:
        """Feed the device's link watchdog."""
        self._ack(Tag.KEEP_ALIVE)

    # ------------------------------------------------------------- commands

    def disable(self) -> None:
        """Bridge off."""
        self._ack(Tag.SET_COMMAND, m.body_command(Mode.Disabled))

    def torque(self, iq_a: float) -> None:
        """Torque mode: q current [A]."""
        self._ack(Tag.SET_COMMAND, m.body_command(Mode.Torque, _real("iq_a", iq_a)))

    def velocity(self, rad_s: float) -> None:
        """Velocity mode [rad/s, output frame]."""
        self._ack(Tag.SET_COMMAND, m.body_command(Mode.Velocity, _real("rad_s", rad_s)))

    def position(self, rad: float) -> None:
        """Position mode [rad, output frame]."""
        self._ack(Tag.SET_COMMAND, m.body_command(Mode.Position, _real("rad", rad)))

    def impedance(
        self,
        position_rad: float,
        velocity_rad_s: float,
        kp: float,
        kd: float,
        torque_ff_nm: float = 0.0,
        torque_limit_nm: float = math.inf,
    ) -> None:
        """Impedance mode (output frame): ``kp`` [N m/rad], ``kd``
        [N m s/rad], feed-forward and torque limit [N m] (``inf``: the
        current limit's)."""
        vals = [
            _real("position_rad", position_rad),
            _real("velocity_rad_s", velocity_rad_s),
            _real("kp", kp),
            _real("kd", kd),
            _real("torque_ff_nm", torque_ff_nm),
            _real("torque_limit_nm", torque_limit_nm),
        ]
        self._ack(Tag.SET_COMMAND, m.body_command(Mode.Impedance, *vals))

    def open_loop(
        self,
        v_d_v: float,
        v_q_v: float,
        theta_e_rad: float = 0.0,
        omega_e_rad_s: float = 0.0,
    ) -> None:
        """Open-loop voltage: ``v_d``, ``v_q`` [V] at electrical angle
        ``theta_e_rad`` turning at ``omega_e_rad_s`` [rad/s electrical]."""
        theta = _real("theta_e_rad", theta_e_rad)
        if not math.isfinite(theta):
            raise ValueError("theta_e_rad must be finite")
        bits = int(round(theta / (2 * math.pi) * 2**32)) % 2**32
        body = m.body_open_loop(
            _real("v_d_v", v_d_v), _real("v_q_v", v_q_v), bits, _real("omega_e_rad_s", omega_e_rad_s)
        )
        self._ack(Tag.SET_COMMAND, body)

    # ------------------------------------------------------------- settings

    def set_limits(
        self,
        *,
        max_current_a: float,
        max_velocity_rad_s: float,
        min_position_rad: float,
        max_position_rad: float,
        max_open_loop_voltage_v: float,
        max_open_loop_omega_e_rad_s: float,
        max_kp_nm_per_rad: float,
        max_kd_nm_s_per_rad: float,
    ) -> None:
        """Replace the motor's command limits (all eight, rotor frame; only
        while disabled)."""
        vals = [
            _real(n, v)
            for n, v in (
                ("max_current_a", max_current_a),
                ("max_velocity_rad_s", max_velocity_rad_s),
                ("min_position_rad", min_position_rad),
                ("max_position_rad", max_position_rad),
                ("max_open_loop_voltage_v", max_open_loop_voltage_v),
                ("max_open_loop_omega_e_rad_s", max_open_loop_omega_e_rad_s),
                ("max_kp_nm_per_rad", max_kp_nm_per_rad),
                ("max_kd_nm_s_per_rad", max_kd_nm_s_per_rad),
            )
        ]
        self._ack(Tag.SET_LIMITS, m.body_limits(*vals))

    def set_current_gains(self, kp_d: float, ki_d: float, kp_q: float, ki_q: float) -> None:
        """Current-loop PI gains of both axes [V/A, V/(A s)]."""
        vals = [_real(n, v) for n, v in (("kp_d", kp_d), ("ki_d", ki_d), ("kp_q", kp_q), ("ki_q", ki_q))]
        self._ack(Tag.SET_CURRENT_GAINS, m.body_current_gains(*vals))

    def set_speed_gains(self, kp_a_per_rad_s: float, ki_a_per_rad: float) -> None:
        """Speed-loop PI gains (rotor frame)."""
        self._ack(
            Tag.SET_SPEED_GAINS,
            m.body_speed_gains(
                _real("kp_a_per_rad_s", kp_a_per_rad_s), _real("ki_a_per_rad", ki_a_per_rad)
            ),
        )

    def set_position_gains(
        self, kp_per_s: float, max_velocity_rad_s: float, max_acceleration_rad_s2: float
    ) -> None:
        """Position-loop gain and trajectory limits (rotor frame)."""
        self._ack(
            Tag.SET_POSITION_GAINS,
            m.body_position_gains(
                _real("kp_per_s", kp_per_s),
                _real("max_velocity_rad_s", max_velocity_rad_s),
                _real("max_acceleration_rad_s2", max_acceleration_rad_s2),
            ),
        )

    def set_dividers(self, speed: int, position: int) -> None:
        """Loop dividers: speed loop every ``speed``, position loop every
        ``position`` current-loop periods (only while disabled)."""
        self._ack(
            Tag.SET_DIVIDERS,
            m.body_dividers(_uint("speed", speed, 16), _uint("position", position, 16)),
        )

    def set_watchdog(self, timeout_periods: int, reaction: Union[str, int] = "disable") -> None:
        """Link watchdog: ``reaction`` (``"disable"``, ``"stop"``,
        ``"hold"``) after ``timeout_periods`` current-loop periods without a
        command or keep-alive (0: off)."""
        r = _choice("reaction", reaction, m.TimeoutReaction)
        self._ack(
            Tag.SET_WATCHDOG,
            m.body_watchdog(_uint("timeout_periods", timeout_periods, 32), r),
        )

    def calibrate(self, routine: Union[str, int]) -> None:
        """Start a calibration routine (``"offsets"``, ``"identification"``,
        ``"alignment"``, ``"anticogging"``, ``"encoder_linearisation"``);
        returns once started (only while disabled)."""
        r = _choice("routine", routine, m.Calibration)
        self._ack(Tag.RUN_CALIBRATION, m.body_calibration(r))

    def wait_calibration(self, timeout: float = 120.0, poll: float = 0.05) -> None:
        """Wait for the calibration running to end (``calibration-result``
        no longer 1, running); raises :class:`CalibrationError` when it
        failed or was aborted (the step and the reason in words), a
        :class:`TimeoutError` when it still runs after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        seen = False
        while True:
            result = int(self.param(ParamId.CalibrationResult))
            if result == 1:
                seen = True
            elif seen or result != 0:
                break
            if time.monotonic() > deadline:
                raise TimeoutError(f"the calibration still runs after {timeout:g} s")
            time.sleep(poll)
        if result == 2:
            return
        step = int(self.param(ParamId.CalibrationStep))
        step_name = m.CALIBRATION_STEPS[step] if step < len(m.CALIBRATION_STEPS) else f"step {step}"
        if result >= m.CALIBRATION_FAILED_BASE:
            n = result - m.CALIBRATION_FAILED_BASE
            why = m.CALIBRATION_FAILURES[n] if n < len(m.CALIBRATION_FAILURES) else f"reason {n}"
            raise CalibrationError(step_name, f"failed at {step_name}: {why}")
        what = m.CALIBRATION_RESULTS[result] if result < len(m.CALIBRATION_RESULTS) else f"result {result}"
        raise CalibrationError(step_name, f"{step_name}: {what}")

    def calibrate_cogging(self, wait: bool = True, timeout: float = 120.0) -> float:
        """Measure the anticogging map (design §32): a slow sweep both ways on
        the closed loop, about 24 s; the map is installed switched on and kept
        by the next :meth:`save_config`. Only while disabled, on a calibrated
        drive with the angle known at low speed: refused (:class:`NackError`,
        ``NotCalibrated`` or ``Unsupported``, the reason in words) otherwise.
        With ``wait``, returns the map's peak [A] once done
        (:class:`CalibrationError` if it failed); without, 0 once started."""
        self.calibrate(m.Calibration.anticogging)
        if not wait:
            return 0.0
        self.wait_calibration(timeout)
        return self.param(ParamId.AnticoggingPeakA)

    def calibrate_encoder(self, wait: bool = True, timeout: float = 60.0) -> float:
        """Learn the angle sensor's correction (design §33, encoder
        linearisation): turns at a constant speed both ways, about 6 s; the
        correction is installed switched on and kept by the next
        :meth:`save_config`. Only while disabled, on a calibrated drive with a
        fine angle sensor (not halls, not sensorless). With ``wait``, returns
        the correction's peak [rad, mechanical] once done; without, 0 once
        started."""
        self.calibrate(m.Calibration.encoder_linearisation)
        if not wait:
            return 0.0
        self.wait_calibration(timeout)
        return self.param(ParamId.EncoderCorrectionPeakRad)

    # --------------------------------------------------------------- reads

    def faults(self) -> FaultReport:
        """Latched faults (falsy when none)."""
        return m.decode_faults(self._expect(Tag.READ_FAULTS, b"", Tag.FAULTS))

    def clear_faults(self) -> None:
        """Clear the latched faults."""
        self._ack(Tag.CLEAR_FAULTS)

    @staticmethod
    def _param_id(name_or_id: Union[str, int, ParamId]) -> ParamId:
        if isinstance(name_or_id, str):
            if name_or_id in m.PARAM_BY_NAME:
                return m.PARAM_BY_NAME[name_or_id]
            try:
                return ParamId[name_or_id]
            except KeyError:
                names = ", ".join(m.PARAM_NAMES.values())
                raise ValueError(f"unknown parameter {name_or_id!r} (one of {names})") from None
        return _choice("parameter", name_or_id, ParamId)

    def param(self, name_or_id: Union[str, int, ParamId]) -> float:
        """One parameter by ``foc-ctl`` name (``"pole-pairs"``), :class:`ParamId` name or id."""
        pid = self._param_id(name_or_id)
        got, value = m.decode_param(self._expect(Tag.READ_PARAM, m.body_read_param(pid), Tag.PARAM))
        if got != pid:
            raise ProtocolError(f"asked for parameter {int(pid)}, got {got}")
        return value

    def set_param(self, name_or_id: Union[str, int, ParamId], value: Union[float, bool]) -> None:
        """Write a parameter (the d-current reference's, design §30:
        ``"field-weakening"``, ``"mtpa"``, ``"short-circuit"`` take
        ``True``/``False`` or 1/0, ``"max-id"`` a current [A]; the tables'
        switches, design §32, §33: ``"anticogging"``,
        ``"encoder-linearisation"``; only while disabled). A refusal changes
        nothing: :class:`NackError` ``OutOfRange`` (field 1: the value) for a
        value the parameter does not take, ``Unsupported`` when the drive's
        rule refuses it (field weakening on halls, or with max-id 0),
        ``NotCalibrated`` for a table's switch on without the table."""
        pid = self._param_id(name_or_id)
        if pid not in m.WRITABLE_PARAMS:
            names = ", ".join(m.PARAM_NAMES[p] for p in m.WRITABLE_PARAMS)
            raise ValueError(f"{m.PARAM_NAMES.get(pid, pid)} cannot be written (one of {names})")
        if isinstance(value, bool):
            v = 1.0 if value else 0.0
        else:
            v = _real(m.PARAM_NAMES[pid], value)
        self._ack(Tag.SET_PARAM, m.body_set_param(pid, v))

    def params(self) -> Dict[str, float]:
        """Every parameter the device answers, by ``foc-ctl`` name (those it
        refuses, e.g. not simulated or newer than its protocol, are left out)."""
        out: Dict[str, float] = {}
        for pid, name in m.PARAM_NAMES.items():
            try:
                out[name] = self.param(pid)
            except NackError as e:
                if e.code not in (
                    ErrorCode.Unsupported,
                    ErrorCode.OutOfRange,
                    ErrorCode.UnknownMessage,
                ):
                    raise
        return out

    def telemetry(self) -> Telemetry:
        """One telemetry sample now."""
        return m.decode_telemetry(self._expect(Tag.READ_TELEMETRY, b"", Tag.TELEMETRY))

    # ------------------------------------------------------------- streaming

    def start_stream(
        self, rate_hz: Optional[float] = None, *, every_periods: Optional[int] = None
    ) -> None:
        """Start streaming telemetry at ``rate_hz`` (converted by the device
        to whole periods) or every ``every_periods`` current-loop periods."""
        if (rate_hz is None) == (every_periods is None):
            raise ValueError("give exactly one of rate_hz and every_periods")
        if rate_hz is not None:
            body = m.body_start_telemetry(_real("rate_hz", rate_hz))
        else:
            body = m.body_start_telemetry(
                every_periods=_uint("every_periods", every_periods, 32)
            )
        self._last_stream_seq = None
        self._ack(Tag.START_TELEMETRY, body)

    def stop_stream(self) -> None:
        """Stop streaming."""
        self._ack(Tag.STOP_TELEMETRY)

    def next_sample(self, timeout: float) -> Optional[StreamSample]:
        """The next streamed sample (queued first), waiting at most
        ``timeout`` [s]; ``None`` when none came."""
        deadline = time.monotonic() + timeout
        while True:
            if self._queue:
                return self._queue.popleft()
            if time.monotonic() >= deadline:
                return None
            self._pump(deadline)
            while self._replies:
                self._replies.popleft()
                self.stats.stale_replies += 1

    def clear_stream_queue(self) -> None:
        """Drop queued streamed samples."""
        self._queue.clear()

    def stream(
        self,
        rate_hz: Optional[float] = None,
        duration_s: float = 1.0,
        *,
        every_periods: Optional[int] = None,
        on_sample: Optional[Callable[[StreamSample], None]] = None,
    ) -> StreamData:
        """Stream telemetry for ``duration_s`` and return the samples as
        numpy arrays (see :class:`StreamData`; ``lost`` counts samples lost
        by gaps in the stream counter). ``rate_hz`` defaults to 100 Hz
        unless ``every_periods`` is given. The stream is stopped at the end,
        also on error."""
        duration = _real("duration_s", duration_s)
        if not math.isfinite(duration) or duration < 0:
            raise ValueError("duration_s must be finite and >= 0")
        if rate_hz is None and every_periods is None:
            rate_hz = 100.0
        try:
            pwm_hz: Optional[float] = self.param(ParamId.PwmFrequencyHz)
        except NackError:
            pwm_hz = None
        self.clear_stream_queue()
        lost0 = self.stats.stream_lost
        samples: List[StreamSample] = []
        self.start_stream(rate_hz, every_periods=every_periods)
        end = time.monotonic() + duration
        try:
            while True:
                now = time.monotonic()
                if now >= end:
                    break
                s = self.next_sample(end - now)
                if s is not None:
                    samples.append(s)
                    if on_sample is not None:
                        on_sample(s)
        finally:
            self.stop_stream()
        self.clear_stream_queue()
        return self._stream_arrays(samples, self.stats.stream_lost - lost0, duration, pwm_hz)

    @staticmethod
    def _stream_arrays(
        samples: Sequence[StreamSample], lost: int, duration: float, pwm_hz: Optional[float]
    ) -> StreamData:
        d = StreamData()
        for name in m.TELEMETRY_FIELDS:
            dtype = _STREAM_DTYPES.get(name, np.float64)
            d[name] = np.array([getattr(s.sample, name) for s in samples], dtype=dtype)
        d["seq"] = np.array([s.seq for s in samples], dtype=np.uint16)
        d["host_time_s"] = np.array([s.host_time_s for s in samples], dtype=np.float64)
        if len(samples) and pwm_hz and pwm_hz > 0:
            steps = np.diff(d["period"].astype(np.int64)) % (1 << 32)
            d["t"] = np.concatenate(([0], np.cumsum(steps))).astype(np.float64) / pwm_hz
        else:
            d["t"] = d["host_time_s"] - (d["host_time_s"][0] if len(samples) else 0.0)
        d.lost = lost
        d.received = len(samples)
        d.duration_s = duration
        return d

    # ---------------------------------------------------------------- config

    def read_config(self, source: Union[str, int] = "live") -> bytes:
        """The whole live or stored configuration record (the foc-store
        envelope: version, length, body, CRC), read chunk by chunk."""
        src = _choice("source", source, m.ConfigSource)
        timeout = self.timeout if src == m.ConfigSource.live else self._flash_timeout()
        record = bytearray()
        total: Optional[int] = None
        # Every chunk but the last carries at least one byte: bounded.
        for _ in range(m.MAX_RECORD + 1):
            offset = len(record)
            body = self._expect(
                Tag.READ_CONFIG, m.body_read_config(src, offset), Tag.CONFIG_CHUNK, timeout
            )
            c = m.decode_chunk(body)
            if c.total > m.MAX_RECORD:
                raise TransferError(f"the device announced a {c.total}-byte record (at most {m.MAX_RECORD})")
            if total is not None and c.total != total:
                raise TransferError(
                    f"the record's length changed during the read ({total} then {c.total} bytes)"
                )
            if c.offset != offset:
                raise TransferError(f"asked for the chunk at {offset}, the device sent {c.offset}")
            if (not c.data and offset < c.total) or offset + len(c.data) > c.total:
                raise TransferError(
                    f"the device sent {len(c.data)} byte(s) at offset {offset} of a "
                    f"{c.total}-byte record"
                )
            total = c.total
            record += c.data
            if len(record) >= total:
                return bytes(record)
        raise TransferError("the record read did not finish")  # pragma: no cover

    def stage_config(self, record: bytes) -> None:
        """Write ``record`` to the device's staging buffer (chunked
        ``WriteConfig``); nothing is applied until a ``Store`` apply."""
        if not isinstance(record, (bytes, bytearray, memoryview)):
            raise TypeError("a configuration record is bytes")
        record = bytes(record)
        if not 1 <= len(record) <= m.MAX_RECORD:
            raise ValueError(f"a record of {len(record)} bytes cannot be sent (1 to {m.MAX_RECORD})")
        for start in range(0, len(record), m.CHUNK_BYTES):
            chunk = record[start : start + m.CHUNK_BYTES]
            self._ack(Tag.WRITE_CONFIG, m.body_chunk(start, len(record), chunk))

    def store(self, op: Union[str, int]) -> None:
        """A store operation (``"save"``, ``"load"``, ``"erase"``,
        ``"apply"``, ``"apply_and_save"``; only while disabled), waiting
        up to ``store_timeout`` per attempt."""
        o = _choice("op", op, m.StoreOp)
        self._ack(Tag.STORE, m.body_store(o), self._flash_timeout())

    def write_config(self, record: bytes, op: Union[str, int] = "apply") -> None:
        """Send ``record`` (chunked ``WriteConfig``), then apply it
        (``op="apply"``) or apply and save it (``"apply_and_save"``). The
        device validates the whole record first: a refusal
        (``NackError`` ``BadRecord``) changes nothing."""
        o = _choice("op", op, m.StoreOp)
        if o not in (m.StoreOp.apply, m.StoreOp.apply_and_save):
            raise ValueError('op is "apply" or "apply_and_save"')
        self.stage_config(record)
        self.store(o)

    def save_config(self) -> None:
        """Save the configuration in force to the drive's flash."""
        self.store(m.StoreOp.save)

    def load_config(self) -> None:
        """Apply the stored record."""
        self.store(m.StoreOp.load)

    def erase_config(self) -> None:
        """Erase the store (the configuration in force is kept)."""
        self.store(m.StoreOp.erase)

    def save_config_file(self, path: PathLike, source: Union[str, int] = "live") -> int:
        """Write the live (or stored) record to ``path`` as raw bytes (the
        record exactly as the drive sends it; not the TOML of ``foc-ctl
        config export``). Returns its length."""
        record = self.read_config(source)
        with open(path, "wb") as f:
            f.write(record)
        return len(record)

    def load_config_file(self, path: PathLike, op: Union[str, int] = "apply_and_save") -> None:
        """Send a raw record file written by :meth:`save_config_file` and
        apply (and by default save) it."""
        with open(path, "rb") as f:
            record = f.read()
        self.write_config(record, op)

    # ----------------------------------------------------------------- joint

    def read_joint(self) -> JointSettings:
        """The joint in force."""
        return m.decode_joint(self._expect(Tag.READ_JOINT, b"", Tag.JOINT))

    def set_joint(self, settings: Optional[JointSettings] = None, **changes: Any) -> JointSettings:
        """Set the joint: ``settings``, or the joint in force with
        ``changes`` (field names of :class:`JointSettings`). Returns what
        was sent."""
        base = settings if settings is not None else self.read_joint()
        j = dataclasses.replace(base, **changes) if changes else base
        for f in dataclasses.fields(j):
            v = getattr(j, f.name)
            if f.name == "entry_blend_periods":
                _uint(f.name, v, 32)
            elif f.name == "travel_out_rad":
                if v is not None:
                    if len(v) != 2:
                        raise ValueError("travel_out_rad is (min, max) or None")
                    _real("travel min", v[0])
                    _real("travel max", v[1])
            else:
                _real(f.name, v)
        self._ack(Tag.SET_JOINT, m.body_joint(j))
        return j

    def home_here(self, home_output_rad: float = 0.0) -> None:
        """Homing to the present position: the output frame's zero is set so
        that the present position reads ``home_output_rad`` [rad, output].
        (Homing to an end stop is not wrapped; use ``foc-ctl home``.)"""
        self._ack(Tag.START_HOMING, b"\x00" + m.f32_bits(_real("home_output_rad", home_output_rad)))

    def read_homing(self) -> Homing:
        """Where homing stands."""
        return m.decode_homing(self._expect(Tag.READ_HOMING, b"", Tag.HOMING))

    # ----------------------------------------------------------------- scope

    def scope_configure(
        self,
        signals: Sequence[SignalSpec],
        divider: int = 1,
        samples: int = 0,
        pre_trigger: int = 0,
        trigger: TriggerSpec = "command",
    ) -> None:
        """Set the scope up (disarms it and drops its data; protocol 4).

        ``signals``: 1 to 8 names (``"iq_a"``, ``"target"`` ...; see
        :class:`ScopeSignal`) or ids. ``divider``: a sample every
        ``divider`` PWM periods. ``samples``: per channel (0: as many as
        fit). ``pre_trigger``: samples kept before the trigger.
        ``trigger``: ``"manual"``, ``"command"`` (a new active command),
        ``"fault"`` (a new fault), or ``("rising" | "falling" | "either",
        signal, level)``.
        """
        ids = parse_signals(signals)
        kind, tsig, level = parse_trigger(trigger)
        body = m.body_scope(
            ids,
            _uint("divider", divider, 16),
            _uint("samples", samples, 16),
            _uint("pre_trigger", pre_trigger, 16),
            kind,
            tsig,
            level,
        )
        self._ack(Tag.SET_SCOPE, body)

    def scope_arm(self) -> None:
        """Arm the scope (starts recording; waits for the trigger)."""
        self._ack(Tag.ARM_SCOPE)

    def scope_trigger(self) -> None:
        """Force the trigger (``NackError`` ``ScopeState`` when not armed)."""
        self._ack(Tag.TRIGGER_SCOPE)

    def scope_status(self) -> ScopeStatus:
        """The scope's configuration and state."""
        return m.decode_scope(self._expect(Tag.READ_SCOPE, b"", Tag.SCOPE))

    def scope_read(self) -> ScopeCapture:
        """Read a finished capture (``NackError`` ``ScopeState`` when the
        capture is not done)."""
        st = self.scope_status()
        n = len(st.signals)
        total = n * st.captured
        if n == 0:
            raise ProtocolError("the scope reports no signals")
        values: List[float] = []
        offset = 0
        while True:
            body = self._expect(
                Tag.READ_SCOPE_DATA, m.body_read_scope_data(offset), Tag.SCOPE_DATA
            )
            got, vals = m.decode_scope_data(body)
            if got != offset:
                raise TransferError(f"asked for scope value {offset}, the device sent {got}")
            if offset + len(vals) > total or (not vals and offset < total):
                raise TransferError(
                    f"the device sent {len(vals)} value(s) at {offset} of {total}"
                )
            values.extend(vals)
            offset += len(vals)
            if offset >= total:
                break
        data = np.array(values, dtype=np.float64).reshape(st.captured, n)
        t = (np.arange(st.captured, dtype=np.float64) - st.trigger_index) * st.sample_period_s
        return ScopeCapture(
            signals=st.signal_names,
            data=data,
            t=t,
            trigger_index=st.trigger_index,
            trigger_period=st.trigger_period,
            sample_period_s=st.sample_period_s,
            status=st,
        )

    def scope_wait(self, wait_s: float, poll_s: float = 0.01) -> ScopeStatus:
        """Poll until the capture is done; :class:`TimeoutError` after ``wait_s``."""
        deadline = time.monotonic() + _real("wait_s", wait_s)
        while True:
            st = self.scope_status()
            if st.state == m.ScopeState.done:
                return st
            if time.monotonic() >= deadline:
                raise TimeoutError(
                    f"the scope capture is not done after {wait_s} s (state {st.state.name})"
                )
            time.sleep(min(poll_s, max(deadline - time.monotonic(), 0.0)))

    def scope_capture(
        self,
        signals: Sequence[SignalSpec],
        action: Optional[Callable[["Drive"], object]] = None,
        *,
        divider: int = 1,
        samples: int = 0,
        pre_trigger: int = 0,
        trigger: TriggerSpec = "command",
        wait_s: float = 1.0,
    ) -> ScopeCapture:
        """Configure, arm, wait until the pre-trigger part is recorded,
        call ``action(drive)`` (the step to record, e.g. ``lambda d:
        d.torque(1.0)``), force the trigger when it is ``"manual"``, wait
        until the capture is done (at most ``wait_s`` after the action)
        and read it."""
        self.scope_configure(signals, divider, samples, pre_trigger, trigger)
        self.scope_arm()
        if pre_trigger > 0:
            # Poll until the pre-trigger samples are recorded (the device's
            # own time; a slow device, e.g. under emulation, takes longer),
            # with a host-time backstop of wait_s.
            deadline = time.monotonic() + wait_s
            while True:
                st = self.scope_status()
                if st.captured >= st.pre_trigger or time.monotonic() >= deadline:
                    break
                time.sleep(0.002)
        if action is not None:
            action(self)
        if parse_trigger(trigger)[0] == m.ScopeTrigger.manual:
            self.scope_trigger()
        self.scope_wait(wait_s)
        return self.scope_read()
