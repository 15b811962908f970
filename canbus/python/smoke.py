#!/usr/bin/env python3
"""Smoke test of foc-canbus with python-can's slcan interface over TCP.

Starts the binary (or uses a running one with --port), opens the bus as a
CANopen master would (python-can `slcan` over pyserial's socket:// URL),
receives the nodes' boot-up messages (kept for the first master), sends
one SYNC and receives the nodes' answers to it.

    python canbus/python/smoke.py [--bin target/debug/foc-canbus] [--node drive|fake] [--port PORT]

Needs python-can and pyserial. Exit status 0 on success.
"""

import argparse
import subprocess
import sys
import time

import can


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="target/debug/foc-canbus")
    ap.add_argument("--node", default="drive", choices=["drive", "fake"])
    ap.add_argument("--nodes", type=int, default=3)
    ap.add_argument("--port", type=int, help="use a running bus on this port")
    a = ap.parse_args()

    proc = None
    port = a.port
    if port is None:
        proc = subprocess.Popen(
            [a.bin, "--nodes", str(a.nodes), "--node", a.node],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        line = proc.stdout.readline().strip()
        print(f"bus: {line}")
        port = int(line.rsplit(":", 1)[1])
    ok = False
    try:
        bus = can.Bus(
            interface="slcan",
            channel=f"socket://127.0.0.1:{port}",
            bitrate=1000000,
            sleep_after_open=0,
        )
        try:
            boot = []
            deadline = time.monotonic() + 5
            while len(boot) < a.nodes and time.monotonic() < deadline:
                m = bus.recv(timeout=0.5)
                if m is not None and 0x701 <= m.arbitration_id <= 0x77F:
                    boot.append(m)
            for m in boot:
                print(f"received boot-up: id=0x{m.arbitration_id:03X} data={m.data.hex()}")
            sync = can.Message(arbitration_id=0x080, is_extended_id=False, data=b"")
            bus.send(sync)
            print("sent SYNC id=0x080")
            answers = []
            deadline = time.monotonic() + 5
            while len(answers) < a.nodes and time.monotonic() < deadline:
                m = bus.recv(timeout=0.5)
                if m is not None and 0x181 <= m.arbitration_id <= 0x1FF:
                    answers.append(m)
            for m in answers:
                print(f"received TPDO: id=0x{m.arbitration_id:03X} data={m.data.hex()}")
            ok = len(boot) == a.nodes and len(answers) == a.nodes
        finally:
            bus.shutdown()
    finally:
        if proc is not None:
            proc.stdin.write("time\nquit\n")
            proc.stdin.flush()
            for line in proc.stdout:
                print(f"control: {line.strip()}")
            proc.wait(timeout=10)
    print("smoke: OK" if ok else "smoke: FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
