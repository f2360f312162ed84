"""The ``fusion`` command as a user's shell runs it: a version, one-line errors, exit codes,
verbosity. Process behaviour (exit status of the interpreter, signals, pipes) runs in a
subprocess; the rest in-process through :func:`fusion.cli.main`."""

from __future__ import annotations

import dataclasses
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from fusion import __version__
from fusion.cli import (
    EXIT_BAD_INPUT,
    EXIT_FAILURE,
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    build_parser,
    main,
)
from fusion.recording import write_recording


def _fusion(*args: str, **kwargs: object) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "fusion", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,  # type: ignore[call-overload]
    )


def _sigint_default() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _one_error_line(err: str, *needles: str) -> None:
    """stderr is a single ``error:`` line, no traceback, naming every needle."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert all(needle in lines[0] for needle in needles), err
    assert "Traceback" not in err


def _truth_only(path: Path) -> Path:
    """A directory with just a three-row truth.csv (what ``sim-plot`` reads)."""
    path.mkdir()
    rows = [f"{t},{t},0,0,1,0,0,0,0,0,1" for t in (0.0, 1.0, 2.0)]
    (path / "truth.csv").write_text("t,e,n,u,ve,vn,vu,roll,pitch,yaw,cycle\n" + "\n".join(rows))
    return path


def test_version() -> None:
    out, err = _fusion("--version").communicate(timeout=60)
    assert out.strip() == f"fusion {__version__}" and err == ""


def test_help_documents_the_exit_statuses() -> None:
    text = build_parser().format_help()
    statuses = text[text.index("exit statuses:") :]
    for code in (0, EXIT_FAILURE, EXIT_USAGE, EXIT_BAD_INPUT, EXIT_INTERRUPTED):
        assert f"\n  {code} " in statuses, code


def test_every_subcommand_takes_quiet_and_verbose() -> None:
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    assert len(commands) >= 9
    for name, sub in commands.items():
        text = sub.format_help()
        assert "--quiet" in text and "--verbose" in text, name


def test_an_unknown_scenario_is_one_line_and_bad_input(tmp_path: Path) -> None:
    proc = _fusion("simulate", "no-such-scenario", str(tmp_path / "rec"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_BAD_INPUT
    _one_error_line(err, "no-such-scenario")


@pytest.mark.parametrize(
    ("override", "named"), [("nope=1", "'nope'"), ("duration_s=abc", "duration_s")]
)
def test_a_bad_set_key_is_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], override: str, named: str
) -> None:
    rec = str(tmp_path / "rec")
    assert main(["simulate", "longwall-random-short", rec, "--set", override]) == EXIT_BAD_INPUT
    _one_error_line(capsys.readouterr().err, named)


def test_an_out_that_is_a_file_or_below_one_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Refused before the recording is read (it need not exist): usage, one line."""
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    run = ["run", "--config", "sins_only", "--recording", str(tmp_path / "rec")]
    assert main([*run, "--out", str(a_file)]) == EXIT_USAGE
    _one_error_line(capsys.readouterr().err, str(a_file), "not a directory")
    below = a_file / "out"
    assert main([*run, "--out", str(below)]) == EXIT_USAGE
    _one_error_line(capsys.readouterr().err, str(below), "cannot be created")
    assert main(["simulate", "longwall-random-short", str(below)]) == EXIT_USAGE
    _one_error_line(capsys.readouterr().err, str(below), "cannot be created")


def test_a_missing_or_unreadable_recording_is_bad_input_for_every_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for rec, found in ((tmp_path / "none", "does not exist"), (a_file, "is not a directory")):
        run = ["run", "--config", "sins_only", "--recording", str(rec)]
        assert main([*run, "--out", str(tmp_path / "out")]) == EXIT_BAD_INPUT
        assert found in capsys.readouterr().err
        assert main(["validate", str(rec)]) == EXIT_BAD_INPUT
        assert found in capsys.readouterr().out
        assert main(["sim-plot", str(rec), str(tmp_path / "t.png")]) == EXIT_BAD_INPUT
        assert found in capsys.readouterr().err
    assert main(["sim-plot", str(tmp_path), str(tmp_path / "t.png")]) == EXIT_BAD_INPUT
    assert "truth.csv: required file is missing" in capsys.readouterr().err


def test_sim_plot_of_a_malformed_truth_or_meta_is_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = _truth_only(tmp_path / "rec")
    truth = rec / "truth.csv"
    truth.write_text(truth.read_text() + "\n3,3,0,0,1,0,0,0,0,0,x\n")
    assert main(["sim-plot", str(rec), str(tmp_path / "a.png")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "truth.csv: cannot be read as 11 numeric columns" in err and "Traceback" not in err
    rec = _truth_only(tmp_path / "rec2")
    (rec / "meta.yaml").write_text("name: a\nname: b\n")
    assert main(["sim-plot", str(rec), str(tmp_path / "b.png")]) == EXIT_BAD_INPUT
    assert "meta.yaml, line 2: duplicate key 'name'" in capsys.readouterr().err


def test_a_clock_outside_its_truth_is_bad_input_for_validate_and_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from test_engine import make_recording

    rec = make_recording(1, duration=5.0, fixes=False)
    assert rec.truth is not None
    late = dataclasses.replace(rec.truth, t=rec.truth.t + 1000.0)
    write_recording(dataclasses.replace(rec, truth=late), tmp_path / "rec")
    assert main(["validate", str(tmp_path / "rec")]) == EXIT_BAD_INPUT
    assert "truth.csv: its time span 1000" in capsys.readouterr().out
    run = ["run", "--config", "sins_only", "--recording", str(tmp_path / "rec")]
    assert main([*run, "--out", str(tmp_path / "out")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "does not overlap imu.csv" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_a_full_disk_is_a_runtime_failure_naming_the_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The figure's file is a link to /dev/full: every write fails with ENOSPC."""
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full on this system")
    figure = tmp_path / "truth.svg"
    figure.symlink_to("/dev/full")
    rec = _truth_only(tmp_path / "rec")
    assert main(["sim-plot", str(rec), str(figure)]) == EXIT_FAILURE
    _one_error_line(capsys.readouterr().err, "No space left on device", str(figure))


@pytest.mark.parametrize(
    ("key", "value", "allowed"),
    [
        ("filter.initial_sigma_scale", ".inf", "[0.001, 1000]"),
        ("filter.initial_sigma_scale", "1.0e+200", "[0.001, 1000]"),
        ("output.rate_hz", "1.0e+9", "[0.01, 1000]"),
        ("output.rate_hz", "1.0e-9", "[0.01, 1000]"),
        ("filter.covariance_step_s", "1.0e-6", "[0.001, 10]"),
        ("filter.covariance_step_s", "1.0e+9", "[0.001, 10]"),
        ("imu.accel_bias_mg", ".nan", "[0, 1000]"),
    ],
)
def test_an_out_of_range_config_value_names_key_value_and_range(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], key: str, value: str, allowed: str
) -> None:
    """``validate-config`` and ``run`` give the same status, before any recording is read."""
    section, name = key.split(".")
    config = tmp_path / "c.yaml"
    config.write_text(f"name: c\n{section}:\n  {name}: {value}\n")
    assert main(["validate-config", str(config)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert f"key {key}: must be a number in {allowed} (found " in err, err
    assert err.count("\n") == 1 and "Traceback" not in err
    run = ["run", "--config", str(config), "--recording", str(tmp_path / "none")]
    assert main(run) == EXIT_BAD_INPUT
    assert allowed in capsys.readouterr().err


def test_a_non_finite_plugin_option_names_its_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "c.yaml"
    config.write_text("name: c\nplugins:\n  - type: odometer\n    sigma_speed_mps: .inf\n")
    assert main(["validate-config", str(config)]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "key plugins[0].sigma_speed_mps: must be a finite number (found inf)" in err, err
    assert err.count("\n") == 1


def test_quiet_keeps_to_warnings_and_verbose_adds_debug(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = _truth_only(tmp_path / "rec")
    assert main(["sim-plot", str(rec), str(tmp_path / "a.png")]) == 0
    assert capsys.readouterr().err.strip() == f"wrote {tmp_path / 'a.png'}"
    assert main(["sim-plot", str(rec), str(tmp_path / "b.png"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"name": "c"}))
    run = ["run", "--config", str(config), "--recording", str(tmp_path / "none")]
    main([*run, "--verbose"])
    assert f"configuration {config.resolve()}" in capsys.readouterr().err
    main(run)
    assert "configuration" not in capsys.readouterr().err


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
    # A shell without job control starts background jobs with SIGINT ignored, and a child
    # inherits that (`.ci/run &` in a script): the child gets the default disposition here.
    proc = _fusion("simulate", "longwall-shift", str(rec), preexec_fn=_sigint_default)
    deadline = time.monotonic() + 60.0
    while not any(tmp_path.glob(".rec.staging-*")) and time.monotonic() < deadline:  # begun
        time.sleep(0.1)
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_INTERRUPTED, err
    assert "fusion simulate: interrupted" in err and "Traceback" not in err
