#!/usr/bin/env python3
"""A velocity step on a drive over TCP, streamed and summarised.

Try it against the simulated device:

    cargo run -p foc-ctl -- simulate --listen 127.0.0.1:4444 &
    python3 python/examples/step.py --port 4444 --velocity 50
"""

import argparse
import sys
import time

import numpy as np

from foc_drive import Drive, NackError


def wait_calibrated(d: Drive, timeout_s: float) -> bool:
    """Poll the calibrated flag until set (False after ``timeout_s``)."""
    deadline = time.monotonic() + timeout_s
    while d.param("calibrated") != 1.0:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=4444)
    ap.add_argument("--velocity", type=float, default=50.0, help="step target [rad/s, output frame]")
    ap.add_argument("--rate", type=float, default=200.0, help="stream rate [Hz]")
    ap.add_argument("--duration", type=float, default=1.0, help="stream duration [s]")
    args = ap.parse_args()

    with Drive.connect_tcp(args.host, args.port) as d:
        hello = d.ping()
        print(f"drive: protocol v{hello.protocol_version}, firmware {hello.firmware}")
        if d.param("calibrated") != 1.0:
            print("not calibrated: running the identification")
            d.calibrate("identification")
            if not wait_calibrated(d, 60.0):
                print("the identification did not finish", file=sys.stderr)
                return 1
        try:
            d.velocity(0.0)
            # The step happens with the stream running: the first sample is
            # taken just after the command.
            d.velocity(args.velocity)
            # A real drive arms its link watchdog (1 s) on the first command:
            # feed it every 20 samples.
            def feed(sample):
                if sample.seq % 20 == 0:
                    d.keep_alive()

            data = d.stream(rate_hz=args.rate, duration_s=args.duration, on_sample=feed)
        except NackError as e:
            print(f"refused: {e}", file=sys.stderr)
            return 1
        finally:
            d.disable()

    t, v, iq = data["t"], data["velocity_rad_s"], data["i_q_a"]
    n = data.received
    if n < 2:
        print("too few samples", file=sys.stderr)
        return 1
    final = float(np.mean(v[-max(n // 10, 1):]))
    rise = np.nonzero(v * np.sign(args.velocity) >= 0.9 * abs(args.velocity))[0]
    settled = np.nonzero(np.abs(v - final) > 0.02 * abs(args.velocity))[0]
    print(f"{n} samples in {t[-1]:.3f} s of drive time ({data.lost} lost)")
    print(f"velocity: {v[0]:.2f} -> {final:.2f} rad/s (target {args.velocity:.2f})")
    if len(rise):
        print(f"90 % rise time: {t[rise[0]] * 1e3:.1f} ms (from the first sample)")
    if len(settled) and settled[-1] + 1 < n:
        print(f"2 % settling: {t[settled[-1] + 1] * 1e3:.1f} ms")
    print(f"peak iq: {np.max(np.abs(iq)):.3f} A, mean bus {np.mean(data['v_bus_v']):.1f} V")
    return 0


if __name__ == "__main__":
    sys.exit(main())
