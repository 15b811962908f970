"""Three drives on one CAN bus from the Python `canopen` package.

Against the host test bus (three simulated drives, nodes 1-3):

    cargo run -p foc-canbus -- --nodes 3 --port 5555 &
    python3 canbus/examples/three_axes.py --channel socket://127.0.0.1:5555

On a real bus, any python-can interface, e.g. SocketCAN:

    python3 canbus/examples/three_axes.py --interface socketcan --channel can0

On the test bus time advances only with SYNC (one per ms), so this master
sends SYNC itself every cycle (on a real bus it would be a periodic SYNC,
`network.sync.start(0.001)`).
"""

import argparse
import math
import os

import canopen

HERE = os.path.dirname(os.path.abspath(__file__))
EDS = os.path.join(HERE, "..", "..", "docs", "canopen", "foc-drive.eds")
INC_PER_REV = 65536  # 0x608F: increments per motor revolution


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--interface", default="slcan")
    ap.add_argument("--channel", default="socket://127.0.0.1:5555")
    ap.add_argument("--nodes", type=int, nargs="+", default=[1, 2, 3])
    a = ap.parse_args()

    network = canopen.Network()
    extra = {"sleep_after_open": 0} if a.interface == "slcan" else {}
    network.connect(interface=a.interface, channel=a.channel, bitrate=1_000_000, **extra)
    sync = lambda n=1: [network.sync.transmit() for _ in range(n)]
    try:
        nodes = []
        for node_id in a.nodes:
            node = canopen.BaseNode402(node_id, EDS)
            node.sdo.RESPONSE_TIMEOUT = 5.0
            network.add_node(node)
            print(node_id, node.sdo[0x1008].raw, "modes", hex(node.sdo[0x6502].raw))
            # csp: target position every SYNC (RPDO2), position actual and
            # following error back every SYNC (TPDO2).
            node.rpdo.read()
            node.tpdo.read()
            node.rpdo[2].clear()
            node.rpdo[2].add_variable(0x607A)
            node.rpdo[2].trans_type = 1
            node.rpdo[2].enabled = True
            node.tpdo[2].clear()
            node.tpdo[2].add_variable(0x6064)
            node.tpdo[2].add_variable(0x60F4)
            node.tpdo[2].trans_type = 1
            node.tpdo[2].enabled = True
            node.rpdo.save()
            node.tpdo.save()
            node.setup_402_state_machine(read_pdos=False)
            node.nmt.state = "OPERATIONAL"
            nodes.append(node)
        sync(100)  # let the drives finish starting
        start = {}
        for node in nodes:
            node.sdo[0x6060].raw = 8  # cyclic synchronous position
            start[node.id] = node.sdo[0x6064].raw
            node.rpdo[2][0x607A].raw = start[node.id]
            node.rpdo[2].transmit()
            sync()
            node.state = "OPERATION ENABLED"
        # One coordinated move: axis k turns k revolutions in one second.
        for ms in range(1200):
            shape = 0.5 * (1 - math.cos(math.pi * min(ms / 1000, 1.0)))
            for k, node in enumerate(nodes, 1):
                node.rpdo[2][0x607A].raw = start[node.id] + round(k * shape * INC_PER_REV)
                node.rpdo[2].transmit()
            sync()
        for node in nodes:
            moved = (node.sdo[0x6064].raw - start[node.id]) / INC_PER_REV
            print(f"node {node.id}: moved {moved:.3f} rev, state {node.state}")
            node.state = "SWITCH ON DISABLED"
    finally:
        network.disconnect()


if __name__ == "__main__":
    main()
