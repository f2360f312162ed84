"""The ``fusion`` command as a user's shell runs it: a version, one-line errors, exit codes."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

from fusion import __version__
from fusion.cli import EXIT_BAD_INPUT, EXIT_INTERRUPTED


def _fusion(*args: str, **kwargs: object) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "fusion", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,  # type: ignore[call-overload]
    )


def test_version() -> None:
    out, err = _fusion("--version").communicate(timeout=60)
    assert out.strip() == f"fusion {__version__}" and err == ""


def test_an_unknown_scenario_is_one_line_and_bad_input(tmp_path: Path) -> None:
    proc = _fusion("simulate", "no-such-scenario", str(tmp_path / "rec"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_BAD_INPUT
    assert err.startswith("error: ") and "no-such-scenario" in err and "Traceback" not in err


def test_a_reader_that_goes_away_is_not_an_error() -> None:
    """``fusion plugins | head -1``: stdout closed before the command writes."""
    proc = _fusion("plugins")
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=60) == 0
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_ctrl_c_stops_with_a_message_and_its_own_status(tmp_path: Path) -> None:
    """SIGINT during the 8-hour shift's simulation (≈ 80 s): status 130, one line."""
    rec = tmp_path / "rec"
    proc = _fusion("simulate", "longwall-shift", str(rec))
    deadline = time.monotonic() + 60.0
    while not any(tmp_path.glob(".rec.staging-*")) and time.monotonic() < deadline:  # begun
        time.sleep(0.1)
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_INTERRUPTED, err
    assert "fusion simulate: interrupted" in err and "Traceback" not in err
