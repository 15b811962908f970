"""The client's link behaviour and the scope against an in-memory device
(fakedevice.FakeDevice): no process, no network."""

import builtins
import math
import struct
import time
import unittest

import numpy as np

import support  # noqa: F401
from fakedevice import FakeDevice, ack, encode_frame, nack, telemetry_body
from foc_drive import Drive, ErrorCode, NackError, ProtocolError, ScopeState, TimeoutError
from foc_drive import messages as m

T = m.Tag


def drive(dev=None, timeout=0.2, retries=3):
    dev = dev or FakeDevice()
    return Drive(dev, timeout=timeout, retries=retries), dev


class Link(unittest.TestCase):
    def test_starts_with_a_delimiter_and_never_uses_seq_zero(self):
        d, dev = drive()
        self.assertEqual(dev.raw_writes[0], b"\x00")
        d._seq = 0xFFFE
        d.ping()
        d.ping()
        d.ping()
        self.assertEqual([f.seq for f in dev.received], [0xFFFF, 1, 2])

    def test_stream_frames_between_replies_are_queued(self):
        d, dev = drive()
        counter = iter([5, 6, 8, 9])

        def hook(f):
            # A stream sample, a stale reply, then the real one.
            return [
                encode_frame(T.STREAM, next(counter), telemetry_body(period=f.seq)),
                ack(f.seq ^ 0x100),
                encode_frame(T.HELLO, f.seq, bytes([4, 1, 2, 3, 64])) if f.tag == T.PING else ack(f.seq),
            ]

        dev.hook = hook
        h = d.ping()
        self.assertEqual(h.firmware, "1.2.3")
        d.keep_alive()
        d.keep_alive()
        d.keep_alive()
        self.assertEqual(d.stats.stream_samples, 4)
        self.assertEqual(d.stats.stream_lost, 1)  # 6 -> 8
        self.assertEqual(d.stats.stale_replies, 4)
        s = [d.next_sample(0.01) for _ in range(5)]
        self.assertEqual([x.seq for x in s[:4]], [5, 6, 8, 9])
        self.assertIsNone(s[4])

    def test_retransmits_the_same_frame_on_timeout(self):
        d, dev = drive(timeout=0.05)
        calls = []

        def hook(f):
            calls.append(f)
            return [] if len(calls) == 1 else None

        dev.hook = hook
        d.keep_alive()
        self.assertEqual(len(calls), 2)
        self.assertEqual(dev.raw_writes[1], dev.raw_writes[2])
        self.assertEqual(d.stats.retransmissions, 1)

    def test_seq_zero_bad_crc_nack_resends_at_once(self):
        d, dev = drive(timeout=5.0)
        calls = []

        def hook(f):
            calls.append(f)
            return [nack(0, ErrorCode.BadCrc)] if len(calls) == 1 else None

        dev.hook = hook
        t0 = time.monotonic()
        d.keep_alive()
        self.assertLess(time.monotonic() - t0, 1.0)
        self.assertEqual(d.stats.retransmissions, 1)

    def test_timeout_is_bounded(self):
        d, dev = drive(timeout=0.05, retries=2)
        dev.hook = lambda f: []
        t0 = time.monotonic()
        with self.assertRaises(TimeoutError) as cm:
            d.ping()
        self.assertIsInstance(cm.exception, builtins.TimeoutError)
        self.assertLess(time.monotonic() - t0, 1.0)
        self.assertEqual(len(dev.received), 3)

    def test_malformed_and_wrong_replies(self):
        d, dev = drive()
        dev.hook = lambda f: [encode_frame(T.TELEMETRY, f.seq, telemetry_body()[:-1])]
        with self.assertRaises(ProtocolError):
            d.telemetry()
        dev.hook = lambda f: [ack(f.seq)]
        with self.assertRaises(ProtocolError):
            d.ping()
        dev.hook = lambda f: [encode_frame(T.ACK, f.seq, b"\x01")]
        with self.assertRaises(ProtocolError):
            d.keep_alive()
        dev.hook = lambda f: [encode_frame(T.PARAM, f.seq, struct.pack("<Bf", 3, 1.0))]
        with self.assertRaises(ProtocolError):
            d.param("pole-pairs")

    def test_nack_carries_code_field_and_name(self):
        d, dev = drive()
        with self.assertRaises(NackError) as cm:
            d.torque(math.nan)  # NaN is sent: the device decides
        e = cm.exception
        self.assertEqual((e.code, e.field, e.field_name, e.code_name), (ErrorCode.OutOfRange, 1, "iq_a", "OutOfRange"))
        self.assertIn("iq_a", str(e))
        dev.hook = lambda f: [nack(f.seq, 99)]
        with self.assertRaises(NackError) as cm:
            d.keep_alive()
        self.assertEqual(cm.exception.code, 99)
        self.assertEqual(cm.exception.code_name, "Other(99)")

    def test_bad_arguments_raise_before_sending(self):
        d, dev = drive()
        n = len(dev.received)
        for call, exc in [
            (lambda: d.torque("1"), TypeError),
            (lambda: d.velocity(None), TypeError),
            (lambda: d.torque(True), TypeError),
            (lambda: d.set_dividers(1.5, 2), TypeError),
            (lambda: d.set_dividers(70000, 1), ValueError),
            (lambda: d.set_watchdog(-1, "stop"), ValueError),
            (lambda: d.set_watchdog(10, "explode"), ValueError),
            (lambda: d.calibrate("nope"), ValueError),
            (lambda: d.param("nope"), ValueError),
            (lambda: d.param(3.0), TypeError),
            (lambda: d.start_stream(10, every_periods=5), ValueError),
            (lambda: d.stage_config(b""), ValueError),
            (lambda: d.stage_config("text"), TypeError),
            (lambda: d.write_config(b"x", op="save"), ValueError),
            (lambda: d.scope_configure([]), ValueError),
            (lambda: d.scope_configure(["iq_a"] * 9), ValueError),
            (lambda: d.scope_configure(["nope"]), ValueError),
            (lambda: d.scope_configure([1.0]), TypeError),
            (lambda: d.scope_configure(["iq_a"], trigger="sometimes"), ValueError),
            (lambda: d.scope_configure(["iq_a"], trigger=("command", "iq_a", 1.0)), ValueError),
            (lambda: d.scope_configure(["iq_a"], divider=0.5), TypeError),
            (lambda: d.open_loop(1.0, 0.0, math.inf), ValueError),
        ]:
            with self.assertRaises(exc):
                call()
        self.assertEqual(len(dev.received), n)

    def test_numpy_numbers_are_accepted(self):
        d, dev = drive()
        d.torque(np.float32(1.5))
        d.set_dividers(np.int64(10), np.uint16(20))
        self.assertEqual(struct.unpack("<HH", dev.received[-1].body), (10, 20))

    def test_open_loop_angle_in_turns(self):
        d, dev = drive()
        d.open_loop(1.0, 2.0, math.pi / 2, 10.0)
        body = dev.received[-1].body
        self.assertEqual(body[0], m.Mode.OpenLoop)
        self.assertEqual(struct.unpack("<ffIf", body[1:]), (1.0, 2.0, 1 << 30, 10.0))
        d.open_loop(0.0, 0.0, -math.pi / 2)
        self.assertEqual(struct.unpack("<I", dev.received[-1].body[9:13])[0], 3 << 30)

    def test_serial_without_pyserial_says_how_to_install_it(self):
        try:
            import serial  # noqa: F401

            self.skipTest("pyserial is installed")
        except ImportError:
            pass
        with self.assertRaises(ImportError) as cm:
            Drive.open_serial("/dev/null")
        self.assertIn("pip install", str(cm.exception))

    def test_context_manager_closes(self):
        dev = FakeDevice()
        with Drive(dev) as d:
            d.ping()
        self.assertTrue(dev.closed)
        self.assertTrue(d.closed)
        with self.assertRaises(ConnectionError):
            d.ping()

    def test_stream_arrays_unwrap_the_period_counter(self):
        from foc_drive.drive import StreamSample

        samples = [
            StreamSample(0.0, i, m.decode_telemetry(telemetry_body(period=p)))
            for i, p in enumerate([2**32 - 200, 2**32 - 100, 0, 100])
        ]
        data = Drive._stream_arrays(samples, 0, 1.0, 20000.0)
        np.testing.assert_allclose(data["t"], [0, 0.005, 0.01, 0.015])
        self.assertEqual(data["period"].dtype, np.uint32)
        self.assertEqual(data.received, 4)


class Scope(unittest.TestCase):
    def test_configure_layout(self):
        d, dev = drive()
        d.scope_configure(["iq_a", 13], divider=2, samples=300, pre_trigger=50, trigger=("falling", "velocity_rad_s", -2.5))
        body = dev.received[-1].body
        self.assertEqual(body[:8], bytes([1, 13] + [255] * 6))
        self.assertEqual(struct.unpack("<HHHBBf", body[8:]), (2, 300, 50, 4, 6, -2.5))

    def test_out_of_range_names_the_field(self):
        d, dev = drive()
        with self.assertRaises(NackError) as cm:
            d.scope_configure(["iq_a"], samples=100, pre_trigger=100)
        self.assertEqual((cm.exception.field, cm.exception.field_name), (10, "pre_trigger"))

    def test_state_errors(self):
        d, dev = drive()
        d.scope_configure(["iq_a"], samples=10)
        with self.assertRaises(NackError) as cm:
            d.scope_trigger()
        self.assertEqual(cm.exception.code, ErrorCode.ScopeState)
        with self.assertRaises(NackError) as cm:
            d.scope_read()
        self.assertEqual(cm.exception.code, ErrorCode.ScopeState)

    def test_capture_on_a_command(self):
        d, dev = drive()
        cap = d.scope_capture(
            ["iq_a", "target", "mode"], lambda drv: drv.torque(0.5), samples=200, pre_trigger=40, wait_s=1.0
        )
        self.assertEqual(cap.signals, ["iq_a", "target", "mode"])
        self.assertEqual(cap.data.shape, (200, 3))
        self.assertEqual(len(cap), 200)
        self.assertEqual(cap.trigger_index, 40)
        self.assertEqual(cap.t[40], 0.0)
        self.assertAlmostEqual(cap.t[41] - cap.t[40], 5e-5)
        np.testing.assert_array_equal(cap["iq_a"][:40], 0.0)
        np.testing.assert_array_equal(cap.target[40:], 0.5)
        np.testing.assert_array_equal(cap.mode[40:], m.Mode.Torque)
        self.assertEqual(set(cap.as_dict()), {"t", "iq_a", "target", "mode"})
        with self.assertRaises(KeyError):
            cap["vq_v"]
        self.assertEqual(d.scope_status().state, ScopeState.done)
        # 600 values at 12 per reply.
        self.assertEqual(sum(1 for f in dev.received if f.tag == T.READ_SCOPE_DATA), 50)

    def test_capture_manual_with_as_many_as_fit(self):
        d, dev = drive()
        dev.scope_capacity = 100
        cap = d.scope_capture([0, 1, 2], trigger="manual", wait_s=1.0)
        self.assertEqual(cap.data.shape, (33, 3))
        np.testing.assert_array_equal(cap["id_a"], np.arange(33.0))

    def test_wait_times_out(self):
        d, dev = drive()
        d.scope_configure(["iq_a"], samples=10)
        d.scope_arm()
        with self.assertRaises(TimeoutError):
            d.scope_wait(0.05)

    def test_short_data_is_a_transfer_error(self):
        d, dev = drive()
        d.scope_capture(["iq_a"], trigger="manual", samples=30)
        def hook(f):
            if f.tag == T.READ_SCOPE_DATA:
                (off,) = struct.unpack("<H", f.body)
                return [encode_frame(T.SCOPE_DATA, f.seq, struct.pack("<HB", off, 0))]
            return None

        dev.hook = hook
        with self.assertRaises(ProtocolError):
            d.scope_read()
        dev.hook = lambda f: (
            [encode_frame(T.SCOPE_DATA, f.seq, struct.pack("<HBf", 7, 1, 0.0))] if f.tag == T.READ_SCOPE_DATA else None
        )
        with self.assertRaises(ProtocolError):
            d.scope_read()


if __name__ == "__main__":
    unittest.main()
