"""Every message layout of the current protocol version, checked against
the Rust side (issue 34).

``vectors/protocol-v<N>.json`` is written by the Rust test
``protocol/tests/layouts.rs`` from the crate's own encoder
(``FOC_BLESS=1 cargo test -p foc-protocol --test layouts``): one instance of
every request and reply variant with its tag, fields and body bytes, and
the tables this package mirrors. Here every request body is built with the
package's ``body_*`` functions and every reply body decoded with its
``decode_*`` functions; a message the package cannot build or decode fails,
so a new Rust message needs its Python counterpart. The ``Drive`` methods
that build request bodies themselves are checked against the same bytes.

JSON conventions: floats are exact f32 values (``"inf"``, ``"-inf"``,
``"nan"`` as strings), enumerations their wire codes, bytes lower-case hex.
"""

import dataclasses
import glob
import json
import math
import os
import re
import struct
import unittest

import support  # noqa: F401
from fakedevice import FakeDevice, ack
from foc_drive import Drive, ProtocolError
from foc_drive import codec
from foc_drive import messages as m

VECTORS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "vectors")


def _newest_vectors() -> str:
    files = glob.glob(os.path.join(VECTORS_DIR, "protocol-v*.json"))
    if not files:
        raise FileNotFoundError(f"no protocol-v*.json in {VECTORS_DIR}")
    return max(files, key=lambda p: int(re.search(r"protocol-v(\d+)\.json$", p).group(1)))


VECTORS_PATH = _newest_vectors()
with open(VECTORS_PATH, encoding="utf-8") as _f:
    DOC = json.load(_f)

NON_FINITE = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}


def num(v):
    """A JSON field value as Python uses it (non-finite floats are strings)."""
    return NON_FINITE.get(v, v) if isinstance(v, str) else v


def f32(x: float) -> bytes:
    return struct.pack("<f", x)


def same(got, want) -> bool:
    """Decoded value ``got`` equals JSON value ``want`` (floats as f32 bits,
    NaN equal to NaN)."""
    want = num(want)
    if isinstance(want, bool) or want is None:
        return got is want or (isinstance(got, bool) and got == want)
    if isinstance(want, float):
        if isinstance(got, bool) or not isinstance(got, (int, float)):
            return False
        if math.isnan(want):
            return math.isnan(got)
        return f32(float(got)) == f32(want)
    if isinstance(want, int):
        return isinstance(got, int) and not isinstance(got, bool) and got == want
    if isinstance(want, list):
        got = list(got)
        return len(got) == len(want) and all(same(g, w) for g, w in zip(got, want))
    return got == want


def entries(direction):
    return [(i, e) for i, e in enumerate(DOC["messages"]) if e["direction"] == direction]


def label(i, e) -> str:
    return f"{VECTORS_PATH} message {i} ({e['direction']} {e['name']}, fields {e['fields']})"


# ------------------------------------------------------- request builders


def _command(f):
    mode = m.Mode(f["mode"])
    if mode == m.Mode.OpenLoop:
        return m.body_open_loop(f["v_d_v"], f["v_q_v"], f["theta_e"], f["omega_e_rad_s"])
    names = m.COMMAND_FIELDS[mode][1:]
    return m.body_command(mode, *(f[n] for n in names))


def _joint(f):
    return m.JointSettings(
        gear_ratio=f["gear_ratio"],
        rotor_at_zero_rad=f["rotor_at_zero_rad"],
        travel_out_rad=(f["travel_min_rad"], f["travel_max_rad"]) if f["travel"] else None,
        fault_margin_rad=f["fault_margin_rad"],
        brake_accel_rad_s2=f["brake_accel_rad_s2"],
        kv_a_per_rad_s=f["kv_a_per_rad_s"],
        entry_blend_periods=f["entry_blend_periods"],
        timeout_kd_nm_s_per_rad=f["timeout_kd_nm_s_per_rad"],
    )


def _homing(f):
    if f["method"] == 0:
        return m.body_homing(f["home_output_rad"])
    names = [x.name for x in dataclasses.fields(m.EndStop)]
    return m.body_homing(f["home_output_rad"], m.EndStop(**{n: f[n] for n in names}))


def _start_telemetry(f):
    if f["kind"] == 0:
        return m.body_start_telemetry(every_periods=f["value"])
    return m.body_start_telemetry(f["value"])


def _chunk(f):
    data = bytes.fromhex(f["data"])
    assert len(data) == f["len"]
    return m.body_chunk(f["offset"], f["total"], data)


def _scope_signals(f):
    return [f[f"signal{i}"] for i in range(m.SCOPE_SLOTS) if f[f"signal{i}"] != m.SCOPE_UNUSED]


def _scope(f):
    return m.body_scope(
        _scope_signals(f),
        f["divider"],
        f["samples"],
        f["pre_trigger"],
        f["trigger"],
        f["trigger_signal"],
        f["level"],
    )


def _empty(f):
    assert not f, f
    return b""


#: Rust request variant -> its body built by this package from the fields.
BUILDERS = {
    "Ping": _empty,
    "KeepAlive": _empty,
    "SetCommand": _command,
    "SetLimits": lambda f: m.body_limits(**f),
    "SetCurrentGains": lambda f: m.body_current_gains(**f),
    "SetSpeedGains": lambda f: m.body_speed_gains(**f),
    "SetPositionGains": lambda f: m.body_position_gains(**f),
    "SetDividers": lambda f: m.body_dividers(**f),
    "SetWatchdog": lambda f: m.body_watchdog(**f),
    "SetJoint": lambda f: m.body_joint(_joint(f)),
    "ReadJoint": _empty,
    "StartHoming": _homing,
    "ReadHoming": _empty,
    "RunCalibration": lambda f: m.body_calibration(f["routine"]),
    "ReadFaults": _empty,
    "ClearFaults": _empty,
    "ReadParam": lambda f: m.body_read_param(f["id"]),
    "SetParam": lambda f: m.body_set_param(f["id"], f["value"]),
    "ReadTelemetry": _empty,
    "StartTelemetry": _start_telemetry,
    "StopTelemetry": _empty,
    "ReadConfig": lambda f: m.body_read_config(f["source"], f["offset"]),
    "WriteConfig": _chunk,
    "Store": lambda f: m.body_store(f["op"]),
    "SetScope": _scope,
    "ArmScope": _empty,
    "TriggerScope": _empty,
    "ReadScope": _empty,
    "ReadScopeData": lambda f: m.body_read_scope_data(f["offset"]),
}

# --------------------------------------------------------- reply decoders


def _telemetry(tag):
    return lambda b: dataclasses.asdict(m.decode_telemetry(b, tag))


def _joint_reply(b):
    d = dataclasses.asdict(m.decode_joint(b))
    if d["travel_out_rad"] is not None:
        d["travel_out_rad"] = list(d["travel_out_rad"])
    return d


def _scope_reply(b):
    d = dataclasses.asdict(m.decode_scope(b))
    d["state"] = int(d["state"])
    d["signals"] = list(d["signals"])
    return d


def _hello(b):
    h = m.decode_hello(b)
    return {
        "protocol_version": h.protocol_version,
        "firmware_version": list(h.firmware_version),
        "max_payload": h.max_payload,
    }


def _ack(b):
    assert m.decode_ack(b) is None
    return {}


#: Rust reply variant -> the fields this package decodes from its body.
DECODERS = {
    "Ack": _ack,
    "Nack": lambda b: dict(zip(("code", "field"), m.decode_nack(b))),
    "Hello": _hello,
    "Faults": lambda b: {"bits": m.decode_faults(b).bits, "first_code": m.decode_faults(b).first_code},
    "Param": lambda b: dict(zip(("id", "value"), m.decode_param(b))),
    "Telemetry": _telemetry(m.Tag.TELEMETRY),
    "Stream": _telemetry(m.Tag.STREAM),
    "ConfigChunk": lambda b: {k: (v.hex() if k == "data" else v) for k, v in dataclasses.asdict(m.decode_chunk(b)).items()},
    "Joint": _joint_reply,
    "Homing": lambda b: {"state": m.decode_homing(b).state, "reason": m.decode_homing(b).reason},
    "Scope": _scope_reply,
    "ScopeData": lambda b: dict(zip(("offset", "values"), m.decode_scope_data(b))),
}


def tag_name(variant: str) -> str:
    """``SetCommand`` -> ``SET_COMMAND`` (the :class:`Tag` member)."""
    return re.sub(r"(?<!^)(?=[A-Z])", "_", variant).upper()


class Messages(unittest.TestCase):
    def test_the_vectors_are_this_packages_protocol(self):
        self.assertIn(DOC["protocol_version"], m.SUPPORTED_PROTOCOL_VERSIONS)
        self.assertEqual(DOC["protocol_version"], max(m.SUPPORTED_PROTOCOL_VERSIONS))

    def test_every_request_body_is_built_alike(self):
        for i, e in entries("request"):
            with self.subTest(i=i, name=e["name"]):
                build = BUILDERS.get(e["name"])
                self.assertIsNotNone(build, f"{label(i, e)}: no body_* builder in foc_drive.messages")
                fields = {k: num(v) for k, v in e["fields"].items()}
                self.assertEqual(build(fields).hex(), e["body_hex"], label(i, e))
                self.assertEqual(m.Tag[tag_name(e["name"])], e["tag"], label(i, e))

    def test_every_reply_body_is_decoded_alike(self):
        for i, e in entries("response"):
            with self.subTest(i=i, name=e["name"]):
                decode = DECODERS.get(e["name"])
                self.assertIsNotNone(decode, f"{label(i, e)}: no decode_* function in foc_drive.messages")
                got = decode(bytes.fromhex(e["body_hex"]))
                self.assertEqual(list(got), list(e["fields"]), f"{label(i, e)}: field names")
                for k, want in e["fields"].items():
                    self.assertTrue(same(got[k], want), f"{label(i, e)}: {k} = {got[k]!r}, Rust {want!r}")
                self.assertEqual(m.Tag[tag_name(e["name"])], e["tag"], label(i, e))

    def test_truncated_and_padded_reply_bodies_are_refused(self):
        for i, e in entries("response"):
            body = bytes.fromhex(e["body_hex"])
            with self.subTest(i=i, name=e["name"]):
                with self.assertRaises(ProtocolError, msg=label(i, e)):
                    DECODERS[e["name"]](body + b"\x00")
                if body:
                    with self.assertRaises(ProtocolError, msg=label(i, e)):
                        DECODERS[e["name"]](body[:-1])

    def test_no_builder_or_decoder_without_a_rust_message(self):
        names = {e["name"] for e in DOC["messages"]}
        self.assertEqual(set(BUILDERS) | set(DECODERS), names)


# Normalised enum member names: case and underscores do not count
# (``apply_and_save`` is ``ApplyAndSave``, ``None_`` is ``None``).
def _norm(name: str) -> str:
    return name.replace("_", "").lower()


#: Rust variant names spelt differently here, per table.
NAME_ALIASES = {"ScopeSignal": {"BusV": "v_bus_v", "ModeCode": "mode"}}

#: JSON code table -> this package's (code, name) pairs.
PY_TABLES = {
    "ErrorCode": m.ErrorCode,
    "Mode": m.Mode,
    "Fault": m.Fault,
    "ActiveLimit": m.ActiveLimit,
    "Calibration": m.Calibration,
    "TimeoutReaction": m.TimeoutReaction,
    "ConfigSource": m.ConfigSource,
    "StoreOp": m.StoreOp,
    "ParamId": m.ParamId,
    "ScopeSignal": m.ScopeSignal,
    "ScopeTrigger": m.ScopeTrigger,
    "ScopeState": m.ScopeState,
    "HomingState": list(enumerate(m.Homing.STATES)),
    "HomingFailure": m.HomingFailure,
}


class Tables(unittest.TestCase):
    def test_tags(self):
        self.assertEqual({t.name: int(t) for t in m.Tag}, DOC["tags"])

    def test_code_tables(self):
        self.assertEqual(set(PY_TABLES), set(DOC["codes"]), "code tables")
        for table, rows in DOC["codes"].items():
            py = PY_TABLES[table]
            pairs = [(int(x), x.name) for x in py] if isinstance(py, type) else py
            aliases = NAME_ALIASES.get(table, {})
            with self.subTest(table=table):
                self.assertEqual([c for c, _ in pairs], [c for c, _ in rows], f"{table} codes")
                for (code, name), (_, rust) in zip(pairs, rows):
                    self.assertEqual(_norm(name), _norm(aliases.get(rust, rust)), f"{table} {code}")

    def test_calibration_tables(self):
        c = DOC["calibration"]
        self.assertEqual(list(m.CALIBRATION_STEPS), c["steps"])
        self.assertEqual(list(m.CALIBRATION_RESULTS), c["results"])
        self.assertEqual(m.CALIBRATION_FAILED_BASE, c["failed_base"])
        self.assertEqual(list(m.CALIBRATION_FAILURES), c["failures"])

    def test_param_names(self):
        self.assertEqual({p.name: n for p, n in m.PARAM_NAMES.items()}, DOC["param_names"])

    def test_param_units_and_writable_params(self):
        self.assertEqual({p.name: u for p, u in m.PARAM_UNITS.items()}, DOC["param_units"])
        self.assertEqual(
            [[p.name, switch] for p, switch in m.WRITABLE_PARAMS.items()], DOC["writable_params"]
        )
        self.assertEqual(set(m.PARAM_RANGES), set(m.WRITABLE_PARAMS))

    def test_request_field_names(self):
        want = {m.Tag[k]: tuple(v) for k, v in DOC["request_fields"].items()}
        self.assertEqual(dict(m.REQUEST_FIELDS), want)
        self.assertEqual(
            {int(k): v for k, v in m.COMMAND_FIELDS.items()},
            {int(k): tuple(v) for k, v in DOC["command_fields"].items()},
        )

    def test_telemetry_layout(self):
        fmt = {"u8": "B", "i16": "h", "u32": "I", "f32": "f"}
        self.assertEqual(list(m.TELEMETRY_LAYOUT), [(n, fmt[t]) for n, t in DOC["telemetry_layout"]])

    def test_constants(self):
        for name, want in DOC["constants"].items():
            with self.subTest(name=name):
                mod = m if hasattr(m, name) else codec
                self.assertTrue(hasattr(mod, name), f"{name} is not mirrored")
                self.assertEqual(getattr(mod, name), want, name)


# --------------------------------------------- what Drive's methods send


def _drive_call(name, f):
    """The ``Drive`` call that sends request ``name`` with fields ``f``, or
    None when the public API cannot express these fields."""
    if name == "SetCommand":
        mode = f["mode"]
        if mode == m.Mode.OpenLoop:
            theta = f["theta_e"] / 2**32 * 2 * math.pi
            return lambda d: d.open_loop(f["v_d_v"], f["v_q_v"], theta, f["omega_e_rad_s"])
        calls = {
            m.Mode.Disabled: lambda d: d.disable(),
            m.Mode.Torque: lambda d: d.torque(f["iq_a"]),
            m.Mode.Velocity: lambda d: d.velocity(f["rad_s"]),
            m.Mode.Position: lambda d: d.position(f["rad"]),
            m.Mode.Impedance: lambda d: d.impedance(*(f[n] for n in m.COMMAND_FIELDS[m.Mode.Impedance][1:])),
        }
        return calls[mode]
    if name == "StartHoming":
        return (lambda d: d.home_here(f["home_output_rad"])) if f["method"] == 0 else None
    if name == "StartTelemetry":
        if f["kind"] == 0:
            return lambda d: d.start_stream(every_periods=f["value"])
        return lambda d: d.start_stream(f["value"])
    if name == "ReadConfig":
        return (lambda d: d.read_config(f["source"])) if f["offset"] == 0 else None
    if name == "WriteConfig":
        data = bytes.fromhex(f["data"])
        ok = f["offset"] == 0 and len(data) == f["total"]
        return (lambda d: d.stage_config(data)) if ok else None
    if name == "SetScope":
        kind = m.ScopeTrigger(f["trigger"])
        if kind in (m.ScopeTrigger.rising, m.ScopeTrigger.falling, m.ScopeTrigger.either):
            trigger = (kind.name, f["trigger_signal"], f["level"])
        elif f["trigger_signal"] == 0 and f32(f["level"]) == f32(0.0):
            trigger = kind.name
        else:
            return None
        args = (_scope_signals(f), f["divider"], f["samples"], f["pre_trigger"], trigger)
        return lambda d: d.scope_configure(*args)
    simple = {
        "Ping": lambda d: d.ping(),
        "KeepAlive": lambda d: d.keep_alive(),
        "SetLimits": lambda d: d.set_limits(**f),
        "SetCurrentGains": lambda d: d.set_current_gains(**f),
        "SetSpeedGains": lambda d: d.set_speed_gains(**f),
        "SetPositionGains": lambda d: d.set_position_gains(**f),
        "SetDividers": lambda d: d.set_dividers(**f),
        "SetWatchdog": lambda d: d.set_watchdog(**f),
        "SetJoint": lambda d: d.set_joint(_joint(f)),
        "ReadJoint": lambda d: d.read_joint(),
        "ReadHoming": lambda d: d.read_homing(),
        "RunCalibration": lambda d: d.calibrate(f["routine"]),
        "ReadFaults": lambda d: d.faults(),
        "ClearFaults": lambda d: d.clear_faults(),
        "ReadParam": lambda d: d.param(f["id"]),
        "SetParam": lambda d: d.set_param(f["id"], f["value"]),
        "ReadTelemetry": lambda d: d.telemetry(),
        "StopTelemetry": lambda d: d.stop_stream(),
        "Store": lambda d: d.store(f["op"]),
        "ArmScope": lambda d: d.scope_arm(),
        "TriggerScope": lambda d: d.scope_trigger(),
        "ReadScope": lambda d: d.scope_status(),
    }
    return simple.get(name)


class DriveSends(unittest.TestCase):
    """The bytes ``Drive``'s methods put on the wire are the Rust bodies
    (the device acknowledges everything; a reply of the wrong kind is the
    expected ProtocolError, after the request went out)."""

    def test_drive_methods_send_the_rust_bodies(self):
        checked = set()
        for i, e in entries("request"):
            fields = {k: num(v) for k, v in e["fields"].items()}
            call = _drive_call(e["name"], fields)
            if call is None:
                continue
            with self.subTest(i=i, name=e["name"]):
                dev = FakeDevice()
                dev.hook = lambda f: [ack(f.seq)]
                d = Drive(dev, timeout=0.2, retries=0)
                try:
                    call(d)
                except ProtocolError:
                    pass
                self.assertTrue(dev.received, label(i, e))
                sent = dev.received[0]
                self.assertEqual((sent.tag, sent.body.hex()), (e["tag"], e["body_hex"]), label(i, e))
                checked.add(e["name"])
        # Everything but what the API has no method for (ReadScopeData is
        # sent by scope_read after a Scope reply).
        self.assertEqual(set(BUILDERS) - checked, {"ReadScopeData"})


if __name__ == "__main__":
    unittest.main()
