"""The drive's scope (protocol version 4): a triggered, per-PWM-period
capture of up to eight signals, read back after the fact."""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from typing import Dict, List, Sequence, Tuple, Union

import numpy as np

from .messages import SCOPE_SLOTS, SCOPE_UNUSED, ScopeSignal, ScopeStatus, ScopeTrigger

__all__ = ["ScopeCapture", "SignalSpec", "TriggerSpec", "parse_signals", "parse_trigger"]

#: A signal by name (``"iq_a"``), :class:`ScopeSignal` or id.
SignalSpec = Union[str, int, ScopeSignal]
#: ``"manual"``, ``"command"``, ``"fault"``, a :class:`ScopeTrigger`, or a
#: crossing ``("rising" | "falling" | "either", signal, level)``.
TriggerSpec = Union[str, ScopeTrigger, Tuple[str, SignalSpec, float]]

_CROSSINGS = (ScopeTrigger.rising, ScopeTrigger.falling, ScopeTrigger.either)


def _signal_id(s: SignalSpec) -> int:
    if isinstance(s, str):
        try:
            return int(ScopeSignal[s])
        except KeyError:
            names = ", ".join(m.name for m in ScopeSignal)
            raise ValueError(f"unknown scope signal {s!r} (one of {names})") from None
    if isinstance(s, bool) or not isinstance(s, numbers.Integral):
        raise TypeError(f"a scope signal is a name or an id, not {type(s).__name__}")
    if not 0 <= int(s) < SCOPE_UNUSED:
        raise ValueError(f"scope signal id {s} is not in 0..254")
    return int(s)


def parse_signals(signals: Sequence[SignalSpec]) -> List[int]:
    """Signal ids of 1 to 8 signals given by name or id."""
    if isinstance(signals, (str, bytes)) or not isinstance(signals, Sequence):
        if isinstance(signals, str):
            signals = [signals]
        else:
            raise TypeError("signals is a sequence of signal names or ids")
    ids = [_signal_id(s) for s in signals]
    if not 1 <= len(ids) <= SCOPE_SLOTS:
        raise ValueError(f"the scope records 1 to {SCOPE_SLOTS} signals, not {len(ids)}")
    return ids


def parse_trigger(trigger: TriggerSpec) -> Tuple[int, int, float]:
    """``(trigger, trigger_signal, level)`` wire fields of a trigger spec."""
    if isinstance(trigger, tuple):
        if len(trigger) != 3:
            raise ValueError("a crossing trigger is (kind, signal, level)")
        kind, sig, level = trigger
        k = parse_trigger(kind)[0] if not isinstance(kind, ScopeTrigger) else int(kind)
        if k not in _CROSSINGS:
            raise ValueError(f"{kind!r} is not a crossing (rising, falling, either)")
        if isinstance(level, bool) or not isinstance(level, numbers.Real):
            raise TypeError("the trigger level is a number")
        return k, _signal_id(sig), float(level)
    if isinstance(trigger, ScopeTrigger):
        k = int(trigger)
    elif isinstance(trigger, str):
        try:
            k = int(ScopeTrigger[trigger])
        except KeyError:
            raise ValueError(
                f"unknown trigger {trigger!r} (manual, command, fault, or "
                "('rising'|'falling'|'either', signal, level))"
            ) from None
    else:
        raise TypeError("trigger is a name or a (kind, signal, level) tuple")
    return k, 0, 0.0


@dataclass
class ScopeCapture:
    """A scope capture read back from the drive.

    ``capture["iq_a"]`` (or ``capture.iq_a``) is one signal's samples
    (numpy, oldest first), ``capture.t`` their times [s] relative to the
    trigger (the sample at ``trigger_index`` is at ``t == 0``).
    """

    signals: List[str]
    """Names of the recorded signals, in channel order."""
    data: np.ndarray
    """Samples, shape ``(captured, len(signals))``."""
    t: np.ndarray
    """Sample times relative to the trigger [s]."""
    trigger_index: int
    trigger_period: int
    """PWM period counter at the trigger."""
    sample_period_s: float
    status: ScopeStatus = field(repr=False)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[:, self.signals.index(name)]
        except ValueError:
            raise KeyError(f"{name!r} was not recorded (recorded: {self.signals})") from None

    def __getattr__(self, name: str) -> np.ndarray:
        # Only called for names that are not attributes.
        signals = self.__dict__.get("signals", ())
        if name in signals:
            return self[name]
        raise AttributeError(name)

    def __len__(self) -> int:
        return int(self.data.shape[0])

    def as_dict(self) -> Dict[str, np.ndarray]:
        """``{"t": ..., name: samples, ...}``."""
        d = {"t": self.t}
        d.update({n: self[n] for n in self.signals})
        return d
