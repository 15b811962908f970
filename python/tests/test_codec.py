"""Framing and message layouts, checked against bytes the Rust side made.

The ``RUST_*`` vectors were captured from ``foc-ctl`` (requests: the bytes
``foc-ctl --tcp`` sent for a command line, after its leading 0x00) and
from ``foc-ctl simulate`` (replies), protocol version 3. test_sim.py
re-captures the request vectors live when the binary is available.
"""

import math
import struct
import unittest

import support  # noqa: F401
from foc_drive import codec
from foc_drive import messages as m
from foc_drive.codec import FrameDecoder, FrameFault, RawFrame, cobs_decode, cobs_encode, encode_frame
from foc_drive.errors import ProtocolError

# foc-ctl command line -> (tag, seq, body) -> the frame foc-ctl sent.
RUST_REQUESTS = [
    (["ping"], m.Tag.PING, b"", "03010105648298e700"),
    (["mode", "velocity", "50"], m.Tag.SET_COMMAND, b"\x02" + struct.pack("<f", 50.0), "03100102020107484227535c6500"),
    (["mode", "torque", "--", "-1.5"], m.Tag.SET_COMMAND, b"\x01" + struct.pack("<f", -1.5), "03100102010107c0bf15b5aa1200"),
    (["param", "pole-pairs"], m.Tag.READ_PARAM, b"\x00", "0323010105fbb5019200"),
    (["watchdog", "100", "stop"], m.Tag.SET_WATCHDOG, struct.pack("<IB", 2000, 1), "03160103d007010601079ba41a00"),
    (["calibrate", "alignment", "--no-wait"], m.Tag.RUN_CALIBRATION, b"\x02", "0320010602397bba6e00"),
    (["faults"], m.Tag.READ_FAULTS, b"", "0321010584c4d5df00"),
    (["clear"], m.Tag.CLEAR_FAULTS, b"", "03220105dd7a93dd00"),
    (["dividers", "10", "20"], m.Tag.SET_DIVIDERS, struct.pack("<HH", 10, 20), "031501020a0214058388c52200"),
]

# Replies of foc-ctl simulate to the first three requests above (seq 1).
RUST_HELLO = "0382010203020106400d07f5e200"  # Hello v3, firmware 0.1.0, 64 bytes
RUST_FAULTS = "038301010101010105e456e11e00"  # no faults
RUST_PARAM = "03840101010107e04081ed863c00"  # pole pairs = 7.0


def decode_one(hexframe):
    frames = FrameDecoder().feed(bytes.fromhex(hexframe))
    assert len(frames) == 1, frames
    return frames[0]


class Crc(unittest.TestCase):
    def test_check_value(self):
        # frame.rs: CRC-32/ISO-HDLC check value.
        self.assertEqual(codec.crc32(b"123456789"), 0xCBF43926)


class Cobs(unittest.TestCase):
    # Vectors of frame.rs's cobs_known_vectors (COBS paper / Wikipedia).
    CASES = [
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
        (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
    ]

    def test_known_vectors(self):
        for raw, enc in self.CASES:
            self.assertEqual(cobs_encode(raw), enc)
            self.assertEqual(cobs_decode(enc), raw)

    def test_254_run_uses_ff_code(self):
        raw = bytes(range(1, 255))
        enc = cobs_encode(raw)
        self.assertEqual(enc[0], 0xFF)
        # frame.rs: cobs_max_len(254) = 256 (the 0xFF block, then a final 01 code).
        self.assertEqual(len(enc), 256)
        self.assertNotIn(0, enc)
        self.assertEqual(cobs_decode(enc), raw)

    def test_round_trip_many(self):
        import random

        rng = random.Random(7)
        for _ in range(500):
            raw = bytes(rng.choice([0, 0, 1, 0x55, 0xFF, rng.randrange(256)]) for _ in range(rng.randrange(0, 600)))
            enc = cobs_encode(raw)
            self.assertNotIn(0, enc)
            self.assertEqual(cobs_decode(enc), raw)

    def test_invalid(self):
        with self.assertRaises(ValueError):
            cobs_decode(b"\x05\x01\x02")
        with self.assertRaises(ValueError):
            cobs_decode(b"\x03\x01\x00")


class Frames(unittest.TestCase):
    def test_requests_match_rust_encoding(self):
        for args, tag, body, hexframe in RUST_REQUESTS:
            with self.subTest(args=args):
                self.assertEqual(encode_frame(tag, 1, body).hex(), hexframe)

    def test_rust_replies_decode(self):
        f = decode_one(RUST_HELLO)
        self.assertEqual((f.tag, f.seq), (m.Tag.HELLO, 1))
        self.assertEqual(m.decode_hello(f.body), m.Hello(3, (0, 1, 0), 64))
        f = decode_one(RUST_FAULTS)
        self.assertEqual(m.decode_faults(f.body), m.FaultReport(0, 0))
        f = decode_one(RUST_PARAM)
        self.assertEqual(m.decode_param(f.body), (m.ParamId.PolePairs, 7.0))

    def test_crc_is_checked(self):
        raw = bytearray(cobs_decode(bytes.fromhex(RUST_HELLO)[:-1]))
        raw[4] ^= 1
        self.assertEqual(FrameDecoder().feed(cobs_encode(bytes(raw)) + b"\0"), [FrameFault("bad_crc")])

    def test_decoder_skips_empty_frames_and_resyncs(self):
        d = FrameDecoder()
        # frame.rs regression: fd 00 01 00 00 -> one COBS error, nothing else.
        self.assertEqual(d.feed(bytes.fromhex("fd00010000")), [FrameFault("cobs")])
        out = d.feed(b"\x01\x00\x00" + bytes.fromhex(RUST_HELLO))
        self.assertEqual(len(out), 1)
        self.assertIsInstance(out[0], RawFrame)
        # Byte by byte.
        out = []
        for b in bytes.fromhex(RUST_PARAM):
            out += d.feed(bytes([b]))
        self.assertEqual([f.tag for f in out], [m.Tag.PARAM])

    def test_too_long_reported_once_then_in_step(self):
        d = FrameDecoder()
        self.assertEqual(d.feed(b"\x01" * 1000), [])
        self.assertEqual(d.feed(b"\x00"), [FrameFault("too_long")])
        self.assertEqual(len(d.feed(bytes.fromhex(RUST_HELLO))), 1)

    def test_truncated(self):
        self.assertEqual(FrameDecoder().feed(cobs_encode(b"\x80\x01") + b"\0"), [FrameFault("truncated")])

    def test_body_too_long_for_a_frame(self):
        encode_frame(0x41, 1, bytes(57))
        with self.assertRaises(ValueError):
            encode_frame(0x41, 1, bytes(58))


class Layouts(unittest.TestCase):
    def test_request_body_sizes(self):
        self.assertEqual(len(m.body_command(m.Mode.Impedance, *[0.0] * 6)), 25)
        self.assertEqual(len(m.body_open_loop(1.0, 2.0, 3, 4.0)), 17)
        self.assertEqual(len(m.body_joint(m.JointSettings())), 37)
        self.assertEqual(len(m.body_chunk(0, 100, bytes(48))), 53)

    def test_scope_request_layout(self):
        body = m.body_scope([1, 13], 2, 300, 50, 3, 1, 0.25)
        self.assertEqual(len(body), 20)
        self.assertEqual(body[:8], bytes([1, 13] + [0xFF] * 6))
        self.assertEqual(struct.unpack("<HHHBBf", body[8:]), (2, 300, 50, 3, 1, 0.25))

    def test_scope_reply(self):
        body = struct.pack(
            "<B8BHHHBBfHHIfH", 3, 1, 13, 14, 255, 255, 255, 255, 255, 1, 200, 50, 1, 0, 0.0, 200, 50, 12345, 5e-5, 4096
        )
        self.assertEqual(len(body), 35)
        s = m.decode_scope(body)
        self.assertEqual(s.state, m.ScopeState.done)
        self.assertEqual(s.signals, (1, 13, 14))
        self.assertEqual(s.signal_names, ["iq_a", "target", "mode"])
        self.assertEqual((s.captured, s.trigger_index, s.trigger_period, s.capacity), (200, 50, 12345, 4096))
        self.assertAlmostEqual(s.sample_period_s, 5e-5)
        with self.assertRaises(ProtocolError):
            m.decode_scope(body[:-1])
        # A used slot after an unused one.
        bad = bytearray(body)
        bad[2] = 0xFF
        with self.assertRaises(ProtocolError):
            m.decode_scope(bytes(bad))

    def test_scope_data(self):
        body = struct.pack("<HB3f", 24, 3, 1.0, 2.0, 3.0)
        self.assertEqual(m.decode_scope_data(body), (24, (1.0, 2.0, 3.0)))
        with self.assertRaises(ProtocolError):
            m.decode_scope_data(struct.pack("<HB", 0, 13) + bytes(52))
        with self.assertRaises(ProtocolError):
            m.decode_scope_data(body + b"\0")

    def test_telemetry(self):
        vals = (7, 0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 2, 0, 99, 24.0, 4, 80, 3, 253, -32768)
        body = struct.pack(m.TELEMETRY_FORMAT, *vals)
        self.assertEqual(len(body), 45)
        t = m.decode_telemetry(body)
        self.assertEqual((t.period, t.i_q_a, t.mode, t.mode_name, t.power_limit), (7, 1.5, 2, "Velocity", 4))
        self.assertTrue(t.brake_on and t.brake_locked)
        self.assertAlmostEqual(t.winding_c, 25.3, places=5)
        self.assertTrue(math.isnan(t.stage_c))
        with self.assertRaises(ProtocolError):
            m.decode_telemetry(body[:-1])
        bad = struct.pack(m.TELEMETRY_FORMAT, *vals[:7], 9, *vals[8:])
        with self.assertRaises(ProtocolError):
            m.decode_telemetry(bad)

    def test_faults_and_joint(self):
        f = m.decode_faults(struct.pack("<IB", (1 << 10) | (1 << 21), 10))
        self.assertEqual(f.faults, [m.Fault.CommandTimeout, m.Fault.TravelLimit])
        self.assertEqual(f.first, m.Fault.CommandTimeout)
        self.assertTrue(f)
        j = m.JointSettings(2.0, 0.5, (-1.0, 1.0), 0.1, 100.0, 0.03, 200, 0.01)
        back = m.decode_joint(m.body_joint(j))
        self.assertEqual(back.travel_out_rad, (-1.0, 1.0))
        self.assertEqual((back.gear_ratio, back.entry_blend_periods), (2.0, 200))

    def test_field_names(self):
        self.assertEqual(m.field_name(m.Tag.SET_LIMITS, b"", 0), "max_current_a")
        self.assertEqual(m.field_name(m.Tag.SET_COMMAND, b"\x01", 1), "iq_a")
        self.assertEqual(m.field_name(m.Tag.SET_COMMAND, b"\x05", 6), "torque_limit_nm")
        self.assertEqual(m.field_name(m.Tag.SET_SCOPE, b"", 10), "pre_trigger")
        self.assertEqual(m.field_name(m.Tag.SET_SCOPE, b"", 13), "level")
        self.assertIsNone(m.field_name(m.Tag.SET_LIMITS, b"", 8))

    def test_f32_overflow_becomes_infinity(self):
        self.assertEqual(struct.unpack("<f", m.f32_bits(1e300))[0], math.inf)
        self.assertTrue(math.isnan(struct.unpack("<f", m.f32_bits(math.nan))[0]))


if __name__ == "__main__":
    unittest.main()
