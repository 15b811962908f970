"""Framing of the command channel: COBS, CRC-32 and the frame layout.

Mirrors ``protocol/src/frame.rs``::

    wire    := COBS(payload) 0x00
    payload := tag:u8 | seq:u16 LE | body | crc:u32 LE
    crc     := CRC-32/ISO-HDLC over tag | seq | body

The payload is at most :data:`MAX_PAYLOAD` bytes. Empty frames (two
delimiters in a row, or ``01 00``) are skipped like an idle line.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Iterable, List, Optional, Union

__all__ = [
    "MAX_PAYLOAD",
    "OVERHEAD",
    "MAX_BODY",
    "crc32",
    "cobs_encode",
    "cobs_decode",
    "encode_frame",
    "decode_payload",
    "RawFrame",
    "FrameFault",
    "FrameDecoder",
]

#: Largest un-stuffed payload (tag + seq + body + CRC) [bytes].
MAX_PAYLOAD = 64
#: Bytes of a payload that are not body: tag (1) + seq (2) + CRC (4).
OVERHEAD = 7
#: Largest body of a message [bytes].
MAX_BODY = MAX_PAYLOAD - OVERHEAD


def crc32(data: bytes) -> int:
    """CRC-32/ISO-HDLC (the zlib/Ethernet CRC; ``crc32(b"123456789") == 0xCBF43926``)."""
    return zlib.crc32(bytes(data)) & 0xFFFFFFFF


def cobs_encode(data: bytes) -> bytes:
    """COBS-stuff ``data`` (no delimiter appended); the result holds no 0x00."""
    out = bytearray([0])
    code_at = 0
    code = 1
    for b in bytes(data):
        if b == 0:
            out[code_at] = code
            code_at = len(out)
            out.append(0)
            code = 1
        else:
            out.append(b)
            code += 1
            if code == 0xFF:
                out[code_at] = code
                code_at = len(out)
                out.append(0)
                code = 1
    out[code_at] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Un-stuff one COBS block sequence (without its delimiter).

    Raises :class:`ValueError` on invalid COBS (a 0x00 inside, or a block
    that runs past the end).
    """
    data = bytes(data)
    out = bytearray()
    i = 0
    n = len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise ValueError("0x00 inside a COBS frame")
        end = i + code
        if end > n:
            raise ValueError("COBS block runs past the end of the frame")
        block = data[i + 1 : end]
        if 0 in block:
            raise ValueError("0x00 inside a COBS frame")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def encode_frame(tag: int, seq: int, body: bytes = b"") -> bytes:
    """A complete wire frame (COBS + delimiter) for ``tag``, ``seq``, ``body``."""
    if not 0 <= tag <= 0xFF:
        raise ValueError(f"tag {tag} is not a byte")
    if not 0 <= seq <= 0xFFFF:
        raise ValueError(f"seq {seq} is not a u16")
    data = struct.pack("<BH", tag, seq) + bytes(body)
    payload = data + struct.pack("<I", crc32(data))
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(
            f"a {len(body)}-byte body does not fit a frame (at most {MAX_BODY})"
        )
    return cobs_encode(payload) + b"\x00"


@dataclass(frozen=True)
class RawFrame:
    """A CRC-checked frame: tag, sequence number and undecoded body."""

    tag: int
    seq: int
    body: bytes
    crc: int


@dataclass(frozen=True)
class FrameFault:
    """A frame that could not be used: ``kind`` is one of ``"too_long"``,
    ``"cobs"``, ``"truncated"``, ``"bad_crc"``."""

    kind: str


def decode_payload(payload: bytes) -> Union[RawFrame, FrameFault]:
    """Check the CRC of an un-stuffed payload and split it."""
    if len(payload) < OVERHEAD:
        return FrameFault("truncated")
    data, crc_bytes = payload[:-4], payload[-4:]
    (crc,) = struct.unpack("<I", crc_bytes)
    if crc32(data) != crc:
        return FrameFault("bad_crc")
    tag, seq = struct.unpack_from("<BH", data)
    return RawFrame(tag, seq, bytes(data[3:]), crc)


class FrameDecoder:
    """Streaming decoder: feed received bytes, get the frames they complete.

    Resynchronises at every 0x00, never raises on input; problems are
    returned as :class:`FrameFault` items.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overflow = False

    def reset(self) -> None:
        """Forget a partly received frame."""
        self._buf.clear()
        self._overflow = False

    def feed(self, data: Iterable[int]) -> List[Union[RawFrame, FrameFault]]:
        """Feed bytes; the frames (or faults) completed by them, in order."""
        out: List[Union[RawFrame, FrameFault]] = []
        for b in bytes(data):
            if b != 0:
                # The stuffed frame can be one byte longer than the payload
                # (plus one per 254): anything longer is too long.
                if len(self._buf) > MAX_PAYLOAD + 1:
                    self._overflow = True
                else:
                    self._buf.append(b)
                continue
            frame = self._finish()
            if frame is not None:
                out.append(frame)
        return out

    def _finish(self) -> Optional[Union[RawFrame, FrameFault]]:
        stuffed = bytes(self._buf)
        overflow = self._overflow
        self.reset()
        if not stuffed:
            return None
        if overflow:
            return FrameFault("too_long")
        try:
            payload = cobs_decode(stuffed)
        except ValueError:
            return FrameFault("cobs")
        if not payload:
            return None
        if len(payload) > MAX_PAYLOAD:
            return FrameFault("too_long")
        return decode_payload(payload)
