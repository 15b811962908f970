"""An in-memory device for client tests: answers requests by the
protocol's rules, with hooks to misbehave, and a scope as protocol
version 4 specifies it (not a test module)."""

from __future__ import annotations

import struct
import threading
import time
from typing import Callable, List, Optional

import support  # noqa: F401
from foc_drive import messages as m
from foc_drive.codec import FrameDecoder, RawFrame, encode_frame
from foc_drive.transport import Transport

T = m.Tag


def nack(seq: int, code: int, field: int = 0) -> bytes:
    return encode_frame(T.NACK, seq, bytes([code, field]))


def ack(seq: int) -> bytes:
    return encode_frame(T.ACK, seq)


def telemetry_body(period: int = 0, iq: float = 0.0, mode: int = 0) -> bytes:
    return struct.pack(
        m.TELEMETRY_FORMAT, period, 0.0, iq, 0.0, 0.0, 0.0, 0.0, mode, 0, 0, 24.0, 0, 100, 0, -32768, -32768
    )


class FakeDevice(Transport):
    """A Transport whose far end is this device. ``received`` holds every
    request frame (raw bytes without delimiter handling) in order."""

    def __init__(self) -> None:
        self._dec = FrameDecoder()
        self._out = bytearray()
        self._lock = threading.Lock()
        self.received: List[RawFrame] = []
        self.raw_writes: List[bytes] = []
        # Hook: (frame) -> replies (None: the default handling).
        self.hook: Optional[Callable[[RawFrame], Optional[List[bytes]]]] = None
        self.closed = False
        self.mode = 0
        self.step_iq = 0.0
        # Scope.
        self.scope_capacity = 4096
        self.scope = None  # (signals, divider, samples, pre, trigger, tsig, level)
        self.scope_state = m.ScopeState.idle
        self.scope_data: List[float] = []
        self.scope_captured = 0
        self.scope_trigger_index = 0

    # Transport ---------------------------------------------------------
    def write(self, data: bytes) -> None:
        self.raw_writes.append(bytes(data))
        for f in self._dec.feed(data):
            if not isinstance(f, RawFrame):
                self._push(nack(0, m.ErrorCode.BadCrc))
                continue
            self.received.append(f)
            replies = self.hook(f) if self.hook else None
            if replies is None:
                replies = self.handle(f)
            for r in replies:
                self._push(r)

    def _push(self, b: bytes) -> None:
        with self._lock:
            self._out += b

    def read(self, max_bytes: int, timeout: float) -> bytes:
        deadline = time.monotonic() + timeout
        while True:
            with self._lock:
                if self._out:
                    # Hand out odd-sized pieces to exercise reassembly.
                    n = min(max_bytes, 7, len(self._out))
                    data = bytes(self._out[:n])
                    del self._out[:n]
                    return data
            if time.monotonic() >= deadline:
                return b""
            time.sleep(min(0.002, max(deadline - time.monotonic(), 0)))

    def close(self) -> None:
        self.closed = True

    # Device ------------------------------------------------------------
    def handle(self, f: RawFrame) -> List[bytes]:
        s = f.seq
        if f.tag == T.PING:
            return [encode_frame(T.HELLO, s, bytes([4, 0, 1, 0, 64]))]
        if f.tag in (T.KEEP_ALIVE, T.SET_DIVIDERS, T.SET_WATCHDOG, T.CLEAR_FAULTS):
            return [ack(s)]
        if f.tag == T.READ_TELEMETRY:
            return [encode_frame(T.TELEMETRY, s, telemetry_body(mode=self.mode))]
        if f.tag == T.READ_PARAM:
            if f.body[0] == m.ParamId.ScopeCapacity:
                return [encode_frame(T.PARAM, s, struct.pack("<Bf", f.body[0], self.scope_capacity))]
            return [encode_frame(T.PARAM, s, struct.pack("<Bf", f.body[0], 20000.0))]
        if f.tag == T.SET_COMMAND:
            mode = f.body[0]
            if mode == m.Mode.Torque:
                (iq,) = struct.unpack("<f", f.body[1:5])
                if not abs(iq) <= 10.0:
                    return [nack(s, m.ErrorCode.OutOfRange, 1)]
                self.mode = mode
                self.step_iq = iq
                if self.scope_state == m.ScopeState.armed and self.scope[4] == m.ScopeTrigger.command:
                    self._capture()
            else:
                self.mode = mode
            return [ack(s)]
        if f.tag == T.SET_SCOPE:
            return [self._set_scope(f)]
        if f.tag == T.ARM_SCOPE:
            if self.scope is None:
                return [nack(s, m.ErrorCode.ScopeState)]
            self.scope_state = m.ScopeState.armed
            return [ack(s)]
        if f.tag == T.TRIGGER_SCOPE:
            if self.scope_state != m.ScopeState.armed:
                return [nack(s, m.ErrorCode.ScopeState)]
            self._capture()
            return [ack(s)]
        if f.tag == T.READ_SCOPE:
            return [encode_frame(T.SCOPE, s, self._scope_body())]
        if f.tag == T.READ_SCOPE_DATA:
            (offset,) = struct.unpack("<H", f.body)
            if self.scope_state != m.ScopeState.done:
                return [nack(s, m.ErrorCode.ScopeState)]
            if offset > len(self.scope_data):
                return [nack(s, m.ErrorCode.OutOfRange, 0)]
            vals = self.scope_data[offset : offset + m.SCOPE_DATA_MAX]
            return [encode_frame(T.SCOPE_DATA, s, struct.pack(f"<HB{len(vals)}f", offset, len(vals), *vals))]
        return [nack(s, m.ErrorCode.UnknownMessage)]

    def _set_scope(self, f: RawFrame) -> bytes:
        s = f.seq
        if len(f.body) != 20:
            return nack(s, m.ErrorCode.Malformed)
        sig = list(f.body[:8])
        divider, samples, pre, trig, tsig = struct.unpack("<HHHBB", f.body[8:16])
        (level,) = struct.unpack("<f", f.body[16:20])
        used = [x for x in sig if x != 0xFF]
        for i, x in enumerate(sig):
            if (x != 0xFF and (x > 14 or i >= len(used))) or (i == 0 and x == 0xFF):
                return nack(s, m.ErrorCode.OutOfRange, i)
        n = len(used)
        if divider < 1:
            return nack(s, m.ErrorCode.OutOfRange, 8)
        if samples * n > self.scope_capacity:
            return nack(s, m.ErrorCode.OutOfRange, 9)
        eff = samples or self.scope_capacity // n
        if pre >= eff:
            return nack(s, m.ErrorCode.OutOfRange, 10)
        if trig > 5:
            return nack(s, m.ErrorCode.OutOfRange, 11)
        if tsig > 14:
            return nack(s, m.ErrorCode.OutOfRange, 12)
        self.scope = (used, divider, eff, pre, trig, tsig, level)
        self.scope_state = m.ScopeState.idle
        self.scope_data = []
        self.scope_captured = 0
        return ack(s)

    def _capture(self) -> None:
        used, divider, eff, pre, *_ = self.scope
        data = []
        for k in range(eff):
            after = k >= pre
            for sid in used:
                if sid in (m.ScopeSignal.iq_a, m.ScopeSignal.iq_ref_a, m.ScopeSignal.target):
                    data.append(self.step_iq if after else 0.0)
                elif sid == m.ScopeSignal.mode:
                    data.append(float(self.mode) if after else 0.0)
                else:
                    data.append(float(k))
        self.scope_data = data
        self.scope_captured = eff
        self.scope_trigger_index = pre
        self.scope_state = m.ScopeState.done

    def _scope_body(self) -> bytes:
        if self.scope is None:
            used, divider, eff, pre, trig, tsig, level = [], 1, 0, 0, 0, 0, 0.0
        else:
            used, divider, eff, pre, trig, tsig, level = self.scope
        slots = used + [0xFF] * (8 - len(used))
        return struct.pack(
            "<B8BHHHBBfHHIfH",
            self.scope_state,
            *slots,
            divider,
            eff,
            pre,
            trig,
            tsig,
            level,
            self.scope_captured,
            self.scope_trigger_index,
            1000,
            divider / 20000.0,
            self.scope_capacity,
        )
