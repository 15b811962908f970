"""The rig around the host test bus for a third-party CANopen master.

The master is the `canopen` package (python-canopen) over `python-can`'s
`slcan` interface, connected through pyserial's ``socket://`` URL to the
bus server (`foc-canbus`), which hosts several drives: each the real drive
code (foc-core) with its own simulated motor, and the project's CANopen
node.

Time on the bus is simulated: every SYNC the master sends advances it by
one communication cycle (0x1006, 1 ms). So the master here is a lockstep
one: `Clock.tick` sends, for every millisecond, the cyclic set-points (a
callback), the SYNC, and every `heartbeat_ms` the master's own heartbeat.
Nothing depends on how fast the machine running the test is.
"""

import logging
import os
import subprocess
import time

import canopen

# python-canopen warns when the mode objects are reached by SDO rather
# than PDO: the tests do that on purpose (modes change rarely).
logging.getLogger("canopen.profiles.p402").setLevel(logging.ERROR)

MASTER_ID = 0x7F
SDO_TIMEOUT_S = 30.0
EDS = os.environ.get("FOC_EDS", os.path.join("docs", "canopen", "foc-drive.eds"))


class Bus:
    """A `foc-canbus` process and a `canopen.Network` connected to it."""

    def __init__(self, nodes=3, extra_args=()):
        binary = os.environ["FOC_CANBUS"]
        self.proc = subprocess.Popen(
            [binary, "--nodes", str(nodes), "--port", "0", *extra_args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        line = self.proc.stdout.readline().strip()
        if not line.startswith("listening "):
            self.proc.kill()
            raise RuntimeError(f"foc-canbus did not start: {line!r}")
        self.port = int(line.rsplit(":", 1)[1])
        self.network = canopen.Network()
        self.network.connect(
            interface="slcan",
            channel=f"socket://127.0.0.1:{self.port}",
            bitrate=1_000_000,
            sleep_after_open=0,
        )
        self.clock = Clock(self.network)

    def control(self, line):
        """One control line to the bus (fault injection, bus-off...): its answer."""
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        answer = self.proc.stdout.readline().strip()
        if not answer.startswith("ok"):
            raise RuntimeError(f"bus control {line!r}: {answer!r}")
        return answer

    def add_402_node(self, node_id):
        node = canopen.BaseNode402(node_id, EDS)
        # The bus answers in order: a request queued behind many SYNCs is
        # answered once the bus has simulated them. This bounds that wait
        # (a slow machine takes longer; the results are the same).
        node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S
        self.network.add_node(node)
        return node

    @staticmethod
    def eds_product(node):
        """The product number the EDS declares (0x1018 sub 2's default)."""
        return node.object_dictionary.device_information.product_number

    def close(self):
        try:
            self.network.disconnect()
        finally:
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.flush()
            except (BrokenPipeError, ValueError):
                pass
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            for stream in (self.proc.stdin, self.proc.stdout):
                try:
                    stream.close()
                except (BrokenPipeError, OSError):
                    pass


class Clock:
    """Lockstep time: one SYNC per millisecond of bus time."""

    def __init__(self, network, heartbeat_ms=100):
        self.network = network
        self.heartbeat_ms = heartbeat_ms
        self.heartbeat = True
        self.ms = 0

    def send_heartbeat(self):
        # NMT state 0x05: operational.
        self.network.send_message(0x700 + MASTER_ID, bytes([0x05]))

    def tick(self, ms=1, before_sync=None):
        """Advance the bus by `ms` cycles; `before_sync(k)` runs before the
        k-th SYNC of this call (k from 0)."""
        for k in range(ms):
            if before_sync is not None:
                before_sync(k)
            self.network.sync.transmit()
            self.ms += 1
            if self.heartbeat and self.ms % self.heartbeat_ms == 0:
                self.send_heartbeat()


def barrier(node):
    """Wait until the bus has handled everything sent so far: an SDO round trip
    (the bus handles frames in order)."""
    return node.sdo[0x1001].raw


def wait_until(predicate, timeout=10.0, step=0.002):
    """Poll `predicate` in wall time (only for replies already on their way)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(step)
    return predicate()
