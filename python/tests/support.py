"""Shared helpers of the tests (not a test module)."""

from __future__ import annotations

import os
import sys

try:
    import foc_drive  # noqa: F401
except ImportError:  # not installed: use the source tree
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    import foc_drive  # noqa: F401

#: The repository root (python/..), where Cargo.toml lives.
REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


import shutil
import signal
import socket
import subprocess
import tempfile
import time
from typing import List, Optional

#: Longest wait for the simulator to accept connections [s] (a `cargo run`
#: may have to build foc-ctl first; FOC_SIM_START_TIMEOUT overrides).
START_TIMEOUT_S = float(os.environ.get("FOC_SIM_START_TIMEOUT", "600"))


def foc_ctl_command() -> Optional[List[str]]:
    """How to run foc-ctl: $FOC_CTL (a binary), else `cargo run -q -p
    foc-ctl --` in the repository; None when neither is available."""
    exe = os.environ.get("FOC_CTL")
    if exe:
        return [exe]
    if shutil.which("cargo") and os.path.exists(os.path.join(REPO_ROOT, "ctl", "Cargo.toml")):
        return ["cargo", "run", "-q", "-p", "foc-ctl", "--"]
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Simulator:
    """`foc-ctl simulate --listen 127.0.0.1:PORT [extra...]` as a
    subprocess (in its own process group, so a `cargo run` and its child
    both end)."""

    def __init__(self, cmd: List[str], extra: Optional[List[str]] = None) -> None:
        self.port = free_port()
        self._log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            cmd + ["simulate", "--listen", f"127.0.0.1:{self.port}"] + (extra or []),
            cwd=REPO_ROOT,
            stdout=subprocess.DEVNULL,
            stderr=self._log,
            start_new_session=True,
        )
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if self.proc.poll() is not None:
                self._log.seek(0)
                err = self._log.read().decode(errors="replace")
                raise RuntimeError(f"foc-ctl simulate exited ({self.proc.returncode}): {err[-2000:]}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5):
                    break
            except OSError:
                if time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError(f"foc-ctl simulate did not listen within {START_TIMEOUT_S} s")
                time.sleep(0.05)

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=5)
        self._log.close()
