"""Exceptions raised by :mod:`foc_drive`."""

from __future__ import annotations

import builtins
from typing import Optional

__all__ = [
    "DriveError",
    "NackError",
    "TimeoutError",
    "ProtocolError",
    "TransferError",
    "CalibrationError",
]


class DriveError(Exception):
    """Base class of every error of this package."""


class NackError(DriveError):
    """The device refused a request (``Nack``); nothing changed on the device.

    Attributes:
        code: the :class:`~foc_drive.ErrorCode` (a plain ``int`` when this
            package does not know the code).
        field: the offending field (0-based, in body order) for
            ``OutOfRange``, else 0.
        field_name: the name of that field when known (``OutOfRange`` only).
        value: the value that was sent in that field, when it is a number
            (``OutOfRange`` only).
        message: a human-readable description: the field, the value sent
            and the range allowed where the device's limits give it.
    """

    def __init__(
        self,
        code: int,
        field: int,
        message: str,
        field_name: Optional[str] = None,
        value: Optional[float] = None,
    ):
        super().__init__(message)
        self.code = code
        self.field = field
        self.field_name = field_name
        self.value = value
        self.message = message

    @property
    def code_name(self) -> str:
        """The code's name as in ``message.rs`` (``"OutOfRange"``...)."""
        return getattr(self.code, "name", f"Other({int(self.code)})")


class TimeoutError(DriveError, builtins.TimeoutError):
    """No reply (or the awaited state) in time.

    Also a builtin :class:`TimeoutError`, so either name catches it.
    """


class ProtocolError(DriveError):
    """A reply that does not follow the protocol (wrong kind, bad layout,
    unsupported protocol version)."""


class TransferError(ProtocolError):
    """A chunked transfer (configuration record, scope data) that does not add up."""


class CalibrationError(DriveError):
    """A calibration the drive ran failed or was aborted (the drive latched
    ``CalibrationFailed``, or a fault or a ``Disable`` stopped it).

    Attributes:
        step: the step where it ended, in words (``"anticogging"``...).
        message: the step and the reason in words.
    """

    def __init__(self, step: str, message: str):
        super().__init__(message)
        self.step = step
        self.message = message
