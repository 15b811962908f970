"""Python client for the FOC drive's command channel.

Pure Python on the documented binary protocol (COBS frames with a
CRC-32; ``protocol/src/message.rs`` of the firmware repository)::

    from foc_drive import Drive

    with Drive.connect_tcp("127.0.0.1", 4444) as d:
        print(d.ping())
        d.calibrate("identification")
        d.velocity(50.0)
        data = d.stream(rate_hz=200, duration_s=1.0)
        print(data["velocity_rad_s"].mean(), data.lost)
"""

from .drive import Drive, LinkStats, StreamData, StreamSample
from .errors import (
    CalibrationError,
    DriveError,
    NackError,
    ProtocolError,
    TimeoutError,
    TransferError,
)
from .messages import (
    ActiveLimit,
    Calibration,
    ErrorCode,
    Fault,
    FaultReport,
    Hello,
    Homing,
    JointSettings,
    Mode,
    ParamId,
    ScopeSignal,
    ScopeState,
    ScopeStatus,
    ScopeTrigger,
    Telemetry,
)
from .scope import ScopeCapture
from .transport import SerialTransport, TcpTransport, Transport

__version__ = "0.1.0"

__all__ = [
    "Drive",
    "LinkStats",
    "StreamData",
    "StreamSample",
    "CalibrationError",
    "DriveError",
    "NackError",
    "ProtocolError",
    "TimeoutError",
    "TransferError",
    "ActiveLimit",
    "Calibration",
    "ErrorCode",
    "Fault",
    "FaultReport",
    "Hello",
    "Homing",
    "JointSettings",
    "Mode",
    "ParamId",
    "ScopeCapture",
    "ScopeSignal",
    "ScopeState",
    "ScopeStatus",
    "ScopeTrigger",
    "Telemetry",
    "SerialTransport",
    "TcpTransport",
    "Transport",
]
