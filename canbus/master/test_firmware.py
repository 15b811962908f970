"""The emulated firmware on the host test bus: a third-party CANopen master
(python-canopen over python-can) runs the drive firmware built for the
`qemu` board, whose CAN port is SLCAN on QEMU's USART3, relayed onto the
bus next to two hosted drives (node IDs 2 and 3).

Run by `cargo xtask canopen` after the host tests: it starts QEMU and
`foc-canbus --nodes 2 --first-id 2 --relay tcp:127.0.0.1:PORT` and sets
FOC_FIRMWARE_BUS to the bus's TCP port. Without it (a plain `unittest
discover` of the host tests) every test here is skipped.

Time: the firmware runs on QEMU's emulated clock (its current loop's
period counter, about 0.4x real time here), not on the bus's SYNC time,
which only moves the hosted drives. So nothing here sends SYNCs or its own
heartbeat: waits are polls by SDO in wall time, each bounded, and the
firmware gets no heartbeat consumer (0x1016), whose timeout it would judge
in its own time against a master's heartbeat sent in wall time.

The tests run in order (test_01 ... test_07) on the one emulated drive.
"""

import os
import struct
import time
import unittest

import canopen

from busrig import EDS, wait_until

PORT = os.environ.get("FOC_FIRMWARE_BUS")
FIRMWARE_ID = 1  # from its store: none here, so the default
HOSTED_IDS = (2, 3)
INC_PER_REV = 65536
SDO_TIMEOUT_S = 5.0
# Start-up of the emulated drive (offsets, sensor check, identification):
# about 10 s of emulated time, several times that in wall time.
STARTUP_WALL_S = 240.0
STEP_WALL_S = 20.0
VELOCITY_WALL_S = 60.0

SW_MASK = 0x006F
SW_SWITCH_ON_DISABLED = 0x0040
SW_READY_TO_SWITCH_ON = 0x0021
SW_SWITCHED_ON = 0x0023
SW_OPERATION_ENABLED = 0x0027
SW_TARGET_REACHED = 1 << 10
MODE_PV = 3


def poll(predicate, timeout, step=0.05):
    """`predicate()` until true, in wall time, at most `timeout` s."""
    return wait_until(predicate, timeout=timeout, step=step)


@unittest.skipUnless(PORT, "FOC_FIRMWARE_BUS not set (run by `cargo xtask canopen`)")
class Firmware(unittest.TestCase):
    """The master connects once; every test continues from the last."""

    @classmethod
    def setUpClass(cls):
        cls.heartbeats = []
        cls.network = canopen.Network()
        cls.fw = canopen.BaseNode402(FIRMWARE_ID, EDS)
        cls.fw.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S
        cls.network.add_node(cls.fw)
        cls.hosted = [cls.network.add_node(canopen.RemoteNode(i, EDS)) for i in HOSTED_IDS]
        for n in cls.hosted:
            n.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT_S
        # Subscribed before the channel opens: the bus hands the first
        # client what it kept since boot (the boot-up messages).
        cls.network.subscribe(0x700 + FIRMWARE_ID, cls.on_heartbeat)
        cls.network.connect(
            interface="slcan",
            channel=f"socket://127.0.0.1:{PORT}",
            bitrate=1_000_000,
            sleep_after_open=0,
        )

    @classmethod
    def on_heartbeat(cls, can_id, data, timestamp):
        if data:
            cls.heartbeats.append((time.monotonic(), data[0]))

    @classmethod
    def tearDownClass(cls):
        cls.network.disconnect()

    # --- helpers ------------------------------------------------------------

    def statusword(self):
        return self.fw.sdo[0x6041].raw

    def controlword(self, cw, want, timeout=STEP_WALL_S):
        """Write the controlword, then poll the statusword (masked) for `want`."""
        self.fw.sdo[0x6040].raw = cw
        ok = poll(lambda: self.statusword() & SW_MASK == want, timeout)
        self.assertTrue(ok, f"controlword {cw:#06x}: statusword {self.statusword():#06x}")

    # --- the sequence -------------------------------------------------------

    def test_01_boot_up(self):
        self.assertTrue(
            poll(lambda: any(s == 0 for _, s in self.heartbeats), STEP_WALL_S),
            f"no boot-up from node {FIRMWARE_ID}: {self.heartbeats[:5]}",
        )
        # The hosted drives answer on the same bus.
        for n in self.hosted:
            self.assertEqual(n.sdo[0x1000].raw & 0xFFFF, 402)

    def test_02_identity_and_configuration(self):
        fw = self.fw
        self.assertEqual(fw.sdo[0x1000].raw & 0xFFFF, 402)
        info = fw.object_dictionary.device_information
        self.assertEqual(fw.sdo[0x1018][1].raw, 0)  # no CiA vendor ID: 0
        self.assertEqual(fw.sdo[0x1018][2].raw, info.product_number)
        self.assertEqual(fw.sdo[0x1018][3].raw, info.revision_number)
        self.assertIn("rust-foc", fw.sdo[0x1008].raw)  # segmented upload
        self.assertIn("QEMU", fw.sdo[0x1009].raw)
        self.assertEqual(fw.sdo[0x2100].raw, FIRMWARE_ID)  # node ID setting
        self.assertEqual(fw.sdo[0x2101].raw, 1000)  # bit rate [kbit/s]
        # The same motor as the hosted drives' (the emulated board's).
        self.assertEqual(fw.sdo[0x2000].raw, self.hosted[0].sdo[0x2000].raw)

    def test_03_heartbeat(self):
        self.fw.sdo[0x1017].raw = 50
        self.assertEqual(self.fw.sdo[0x1017].raw, 50)
        since = time.monotonic()
        self.assertTrue(
            poll(lambda: sum(1 for t, _ in self.heartbeats if t > since) >= 5, STEP_WALL_S),
            "fewer than 5 heartbeats",
        )
        # Pre-operational (0x7F).
        self.assertEqual(self.heartbeats[-1][1], 0x7F)

    def test_04_operational(self):
        fw = self.fw
        # PDOs the way a master sets them: statusword on change (TPDO1);
        # position and velocity not on every change (TPDO3 off, TPDO4
        # at most every 20 ms).
        fw.tpdo.read()
        fw.tpdo[3].enabled = False
        fw.tpdo[4].inhibit_time = 200  # [100 us]
        fw.tpdo.save()
        fw.nmt.state = "OPERATIONAL"
        self.assertTrue(
            poll(lambda: self.heartbeats and self.heartbeats[-1][1] == 0x05, STEP_WALL_S),
            "not operational",
        )

    def test_05_profile_velocity(self):
        fw = self.fw
        # The drive finishes its start-up (identification) first.
        self.assertTrue(
            poll(lambda: self.statusword() & 0x004F == SW_SWITCH_ON_DISABLED,
                 STARTUP_WALL_S, step=0.5),
            f"start-up: statusword {self.statusword():#06x}",
        )
        fw.sdo[0x6060].raw = MODE_PV
        self.assertEqual(fw.sdo[0x6061].raw, MODE_PV)
        fw.sdo[0x6083].raw = 20 * INC_PER_REV  # acceleration [inc/s^2]
        fw.sdo[0x6084].raw = 20 * INC_PER_REV
        fw.sdo[0x60FF].raw = 0
        self.controlword(0x06, SW_READY_TO_SWITCH_ON)  # shutdown
        self.controlword(0x07, SW_SWITCHED_ON)  # switch on
        self.controlword(0x0F, SW_OPERATION_ENABLED)  # enable operation
        target = 5 * INC_PER_REV  # 5 rev/s
        fw.sdo[0x60FF].raw = target
        window = fw.sdo[0x606D].raw
        last = []

        def reached():
            last[:] = [fw.sdo[0x606C].raw]
            return abs(last[0] - target) <= window

        t0 = time.monotonic()
        self.assertTrue(poll(reached, VELOCITY_WALL_S, step=0.1),
                        f"velocity {last} inc/s, target {target} +- {window}")
        print(f"node {FIRMWARE_ID}: 0x606C = {last[0]} inc/s (target {target} +- {window}) "
              f"after {time.monotonic() - t0:.1f} s wall", end=" ... ", flush=True)
        self.assertTrue(
            poll(lambda: self.statusword() & SW_TARGET_REACHED, STEP_WALL_S),
            f"target reached not set: {self.statusword():#06x}",
        )
        self.assertEqual(self.statusword() & SW_MASK, SW_OPERATION_ENABLED)

    def test_06_bad_sdo_requests_abort_and_change_nothing(self):
        fw = self.fw
        objects = ((0x1017, 0), (0x6060, 0), (0x60FF, 0), (0x6083, 0), (0x1A03, 1))
        before = [fw.sdo.upload(i, s) for i, s in objects]
        with self.assertRaises(canopen.SdoAbortedError) as e:
            fw.sdo[0x6041].raw = 0  # read-only statusword
        self.assertEqual(e.exception.code, 0x06010002)
        with self.assertRaises(canopen.SdoAbortedError) as e:
            fw.sdo.upload(0x5FFF, 0)  # no such object
        self.assertEqual(e.exception.code, 0x06020000)
        with self.assertRaises(canopen.SdoAbortedError) as e:
            fw.sdo.download(0x6060, 0, struct.pack("<b", 99))  # no such mode
        self.assertEqual(e.exception.code, 0x06090030)
        self.assertEqual([fw.sdo.upload(i, s) for i, s in objects], before)
        self.assertEqual(self.statusword() & SW_MASK, SW_OPERATION_ENABLED)

    def test_07_disable_and_stop(self):
        fw = self.fw
        self.controlword(0x06, SW_READY_TO_SWITCH_ON)  # shutdown: bridge off
        self.controlword(0x00, SW_SWITCH_ON_DISABLED)  # disable voltage
        fw.nmt.state = "PRE-OPERATIONAL"
        self.assertTrue(
            poll(lambda: self.heartbeats[-1][1] == 0x7F, STEP_WALL_S), "not pre-operational"
        )
        fw.nmt.state = "STOPPED"
        self.assertTrue(poll(lambda: self.heartbeats[-1][1] == 0x04, STEP_WALL_S), "not stopped")


if __name__ == "__main__":
    unittest.main()
