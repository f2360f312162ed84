"""Hostile input to the recording reader, the YAML loader and the engine's in-memory check:
each case is one clear problem naming the file (or part), the line (or sample) and the rule,
never a hang, a crash, gigabytes of memory or kilobytes of raw bytes (issue 30, "Reader")."""

from __future__ import annotations

import gzip
import logging
import os
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fusion.cli import EXIT_BAD_INPUT, main
from fusion.config import ConfigError, load_config, parse_config
from fusion.engine import Engine
from fusion.recording import (
    ImuData,
    OdometerData,
    Problem,
    Recording,
    RecordingError,
    check_recording,
    validate_recording,
    write_recording,
)
from fusion.sim.scenario import ScenarioError, load_scenario
from fusion.yaml_limits import MAX_ALIAS_NODES, MAX_NESTING
from tests.test_recording import get_line, make_recording, only, problems_of, set_line


@pytest.fixture
def rec(tmp_path: Path) -> Path:
    """A small valid recording (tests/test_recording.py's), to be broken by one test."""
    root = tmp_path / "rec"
    write_recording(make_recording(), root)
    return root


# ------------------------------------------------------------------------------------------
# The limited YAML loader, in meta.yaml and in configuration files
# ------------------------------------------------------------------------------------------

# Each level refers to the previous one nine times: 9^8 ≈ 4.3e7 nodes from 1 kB of text.
_BOMB = "extra:\n  l0: &l0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + "".join(
    f"  l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]\n" for i in range(1, 9)
)


def test_alias_bomb_in_meta_extra_is_refused_at_its_line(rec: Path) -> None:
    meta = rec / "meta.yaml"
    n_lines = meta.read_text().count("\n")
    meta.write_text(meta.read_text() + _BOMB)
    p = only(problems_of(rec))
    assert (p.file, p.where) == ("meta.yaml", f"line {n_lines + 6}")  # l4: past 10^4 nodes
    assert p.rule.startswith(f"aliases expand the document by more than {MAX_ALIAS_NODES} nodes")


def test_small_aliases_still_work_and_meta_lines_are_reported(rec: Path) -> None:
    meta = rec / "meta.yaml"
    meta.write_text(meta.read_text() + "extra:\n  a: &a {x: 1}\n  b: *a\n")
    assert validate_recording(rec) == []
    text = meta.read_text().replace("rate_hz: 100.0", "rate_hz: -100.0")
    meta.write_text(text)
    line = text.split("\n").index("  rate_hz: -100.0") + 1
    p = only(problems_of(rec))
    assert p.where == f"key imu.rate_hz (line {line})"


def test_non_utf8_meta_yaml_names_the_line(rec: Path) -> None:
    meta = rec / "meta.yaml"
    meta.write_bytes(meta.read_bytes().replace(b"unit-test", b"unit-t\xe9st"))
    p = only(problems_of(rec))
    assert (p.file, p.where) == ("meta.yaml", "line 2")
    assert p.rule == "not UTF-8 text (byte 0xe9 at column 13)"


def _config(tmp_path: Path, text: str | bytes) -> Path:
    path = tmp_path / "config.yaml"
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


@pytest.mark.parametrize(
    ("text", "line", "rule"),
    [
        ("name: x\nfilter:\n  covariance_step_s: 0.1\n  covariance_step_s: 1.0\n", 4, "duplicate"),
        (
            "name: x\nextra: " + "[" * 5000 + "]" * 5000 + "\n",
            2,
            f"nest deeper than {MAX_NESTING} levels",
        ),
        (b"name: x\ndescription: caf\xc3\n", 2, "not UTF-8 text (byte 0xc3"),
        ("name: x\n" + _BOMB, 7, "aliases expand"),
        ("name: x\nloop: &a [1, *a]\n", 2, "refers to a collection that contains it"),
        ("name: x\nfilter: {covariance_step_s: 0.1\n", 3, "invalid YAML"),
    ],
    ids=["duplicate-key", "5000-deep", "non-utf8", "alias-bomb", "recursive-alias", "syntax"],
)
def test_config_yaml_limits(tmp_path: Path, text: str | bytes, line: int, rule: str) -> None:
    path = _config(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert message.startswith(f"{path}, line {line}: ") and rule in message
    assert "\n" not in message


def test_config_that_is_a_fifo_does_not_block(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "config.yaml")
    with pytest.raises(ConfigError, match="not a regular file: a named pipe"):
        load_config(tmp_path / "config.yaml")


def test_a_scenario_file_goes_through_the_same_limits(tmp_path: Path) -> None:
    """A user's scenario YAML (``fusion simulate my.yaml``): the same loader as configs."""
    bomb = "".join(
        f"{n}: &{n} [{', '.join([f'*{p}' if p else '0'] * 10)}]\n"
        for p, n in zip(["", "a", "b", "c", "d"], "abcde", strict=True)
    )
    cases = [
        ("extends: seed000-carrier\nduration_s: 5\nduration_s: 6\n", 3, "duplicate key"),
        ("extends: seed000-carrier\n" + bomb, 5, "aliases expand the document"),
    ]
    for text, line, rule in cases:
        path = tmp_path / "scenario.yaml"
        path.write_text(text)
        with pytest.raises(ScenarioError) as info:
            load_scenario(path)
        assert str(info.value).startswith(f"scenario {path}, line {line}: ") and rule in str(
            info.value
        )
    os.mkfifo(tmp_path / "pipe.yaml")
    with pytest.raises(ScenarioError, match="not a regular file: a named pipe"):
        load_scenario(tmp_path / "pipe.yaml")


# ------------------------------------------------------------------------------------------
# Non-regular and binary files in a recording
# ------------------------------------------------------------------------------------------


def test_directory_in_place_of_a_csv(rec: Path) -> None:
    (rec / "imu.csv").unlink()
    (rec / "imu.csv").mkdir()
    assert str(only(problems_of(rec))) == "imu.csv: not a regular file: a directory"


def test_fifo_in_place_of_a_csv_or_meta_does_not_block(rec: Path) -> None:
    for name in ("odometer.csv", "meta.yaml"):
        (rec / name).unlink()
        os.mkfifo(rec / name)
    found: list[list[Problem]] = []
    reader = threading.Thread(target=lambda: found.append(validate_recording(rec)), daemon=True)
    reader.start()
    reader.join(timeout=20)
    assert not reader.is_alive(), "the reader blocked on a named pipe"
    assert sorted(map(str, found[0])) == [
        "meta.yaml: not a regular file: a named pipe (FIFO)",
        "odometer.csv: not a regular file: a named pipe (FIFO)",
    ]


def test_dangling_symlink_and_symlink_loop(rec: Path) -> None:
    (rec / "meta.yaml").unlink()
    (rec / "meta.yaml").symlink_to("nowhere.yaml")
    (rec / "truth.csv").unlink()
    (rec / "truth.csv").symlink_to("truth.csv")
    assert sorted(map(str, problems_of(rec))) == [
        "meta.yaml: not a regular file: a dangling symbolic link to 'nowhere.yaml'",
        "truth.csv: not a regular file: a symbolic-link loop",
    ]


def test_symlink_to_a_regular_file_is_read(rec: Path) -> None:
    (rec / "imu.csv").rename(rec.parent / "elsewhere.csv")
    (rec / "imu.csv").symlink_to(rec.parent / "elsewhere.csv")
    assert validate_recording(rec) == []


def test_binary_files_are_a_short_message(rec: Path) -> None:
    """A gzip file named .csv gave 3.4 kB of raw bytes in its message; now one short line."""
    (rec / "imu.csv").write_bytes(gzip.compress((rec / "imu.csv").read_bytes()))
    (rec / "odometer.csv").write_bytes(b"t,speed,d\xe9bit\n0.0,0.0,1\n")  # Latin-1
    (rec / "support.csv").write_bytes(b"\x00\x01\xfe" * 2000)
    assert list(map(str, problems_of(rec))) == [
        "imu.csv: the first bytes are not text: gzip-compressed data (name it imu.csv.gz)",
        "odometer.csv: the header line is not UTF-8 text (byte 0xe9)",
        "support.csv: the first bytes are not text (a NUL byte): expected a CSV header line",
    ]


def test_long_garbage_header_is_cut(rec: Path) -> None:
    set_line(rec / "odometer.csv", 1, "x" * 5000)
    assert len(str(only(problems_of(rec)))) < 300


# ------------------------------------------------------------------------------------------
# Warnings: empty streams, streams outside the IMU's time span
# ------------------------------------------------------------------------------------------


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_header_only_stream_is_a_warning(rec: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The format allows it (missing samples are absent rows), so it is not an error; but a
    sensor that logged nothing is worth saying. A support.csv without rows (no push) is not."""
    (rec / "odometer.csv").write_text("t,speed\n")
    (rec / "support.csv").write_text("t,advance\n")
    with caplog.at_level(logging.WARNING, logger="fusion"):
        assert validate_recording(rec) == []
    assert _warnings(caplog) == [f"{rec}: odometer.csv: the stream has no rows: no samples"]


def test_streams_outside_the_imu_span_are_warnings(
    rec: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The IMU spans 0..2 s; the odometer is shifted to 100..102 s, the magnetometer begins a
    second early and the fixes end a second late (one IMU interval of slack is not reported)."""
    odo = rec / "odometer.csv"
    lines = odo.read_text().strip().split("\n")
    odo.write_text(
        "\n".join([lines[0]] + [f"{float(r.split(',')[0]) + 100!r},0.0" for r in lines[1:]])
    )
    set_line(
        rec / "magnetometer.csv",
        2,
        "-1.0," + get_line(rec / "magnetometer.csv", 2).split(",", 1)[1],
    )
    set_line(rec / "position.csv", 4, "3.0,0.0,0.0,0.0,0.02,0.02,0.02")
    set_line(rec / "uwb.csv", 2, "-0.005," + get_line(rec / "uwb.csv", 2).split(",", 1)[1])
    with caplog.at_level(logging.WARNING, logger="fusion"):
        assert validate_recording(rec) == []
    imu = "imu.csv t=0..2 s"
    assert _warnings(caplog) == [
        f"{rec}: odometer.csv: lies entirely outside the IMU's time span "
        f"(odometer.csv t=100..102 s, {imu}): none of it can be used",
        f"{rec}: magnetometer.csv: begins 1 s before the IMU (magnetometer.csv t=-1..2 s, {imu})",
        f"{rec}: position.csv: ends 1 s after the IMU (position.csv t=0.5..3 s, {imu})",
    ]


def test_warnings_reach_validate_and_run(rec: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Through the "fusion" logger, also beside errors (``run`` fails here on a bad truth
    cell, after reading everything, so that no engine is built)."""
    (rec / "odometer.csv").write_text("t,speed\n")
    expected = f"{rec}: odometer.csv: the stream has no rows: no samples"
    with caplog.at_level(logging.WARNING, logger="fusion"):
        assert main(["validate", str(rec)]) == 0
        assert _warnings(caplog) == [expected]
        caplog.clear()
        set_line(rec / "truth.csv", 3, "x" + get_line(rec / "truth.csv", 3))
        run = ["run", "--config", "sins_only", "--recording", str(rec), "--check"]
        assert main(run) == EXIT_BAD_INPUT
        assert _warnings(caplog) == [expected]


# ------------------------------------------------------------------------------------------
# Recordings built in memory (Python API)
# ------------------------------------------------------------------------------------------

_CONFIG = {"name": "free"}


def _engine_problems(recording: Recording) -> str:
    with pytest.raises(RecordingError) as info:
        Engine(parse_config(_CONFIG), recording)
    return str(info.value)


def test_in_memory_time_backwards_and_non_finite_are_refused() -> None:
    good = make_recording()
    t, gyro = good.imu.t.copy(), good.imu.gyro.copy()
    t[50] = t[48]
    gyro[7, 2] = np.inf
    bad = replace(good, imu=ImuData(t=t, gyro=gyro, accel=good.imu.accel))
    message = _engine_problems(bad)
    assert message.startswith("2 problems with the recording format")
    assert "Recording.imu, sample 7, column wz: value is not a finite number" in message
    assert (
        "Recording.imu, sample 50: time must be strictly increasing (t=0.48 after t=0.49 on "
        "sample 49)" in message
    )


def test_in_memory_physics_rates_sections_and_meta() -> None:
    good = make_recording()
    gyro = good.imu.gyro.copy()
    gyro[3, 0] = 60.0
    meta = good.meta.model_copy(deep=True)
    meta.initial.sigma.position_m = (-1.0, 0.0, 0.0)  # assigned after validation
    message = _engine_problems(replace(good, meta=meta))
    assert "Recording.meta, key initial.sigma.position_m[0]: must be >= 0" in message
    odometer = OdometerData(t=good.odometer.t * 2, speed=good.odometer.speed)  # type: ignore[union-attr]
    message = _engine_problems(
        replace(good, imu=ImuData(good.imu.t, gyro, good.imu.accel), odometer=odometer)
    )
    assert "Recording.imu, sample 3, column wx: |wx| = 60 rad/s exceeds" in message
    assert "Recording.meta, key odometer.rate_hz: rate_hz = 10 Hz disagrees" in message
    no_section = replace(good, meta=good.meta.model_copy(update={"uwb": None}))
    assert "Recording.meta, key uwb: section 'uwb' is required" in _engine_problems(no_section)


def test_in_memory_types_and_shapes() -> None:
    good = make_recording()
    assert "Recording.imu: must be ImuData (found NoneType)" in _engine_problems(
        replace(good, imu=None)  # type: ignore[arg-type]
    )
    with pytest.raises(RecordingError, match=r"ImuData: gyro must have shape \(N, 3\)"):
        ImuData(t=[0.0, 0.01], gyro=np.zeros((2, 2)), accel=np.zeros((2, 3)))
    with pytest.raises(RecordingError, match="OdometerData: could not convert"):
        OdometerData(t=[0.0, 0.1], speed=["fast", "slow"])


def test_in_memory_gap_needs_bridging(caplog: pytest.LogCaptureFixture) -> None:
    good = make_recording()
    keep = (good.imu.t < 0.5) | (good.imu.t > 0.8)
    gappy = replace(good, imu=ImuData(good.imu.t[keep], good.imu.gyro[keep], good.imu.accel[keep]))
    message = _engine_problems(gappy)
    assert "Recording.imu, samples 49-50 (t=0.49..0.81 s): gap of 0.32 s" in message
    assert "bridge_imu_gaps: true" in message
    bridged = check_recording(gappy, bridge_imu_gaps=True)
    assert bridged.imu_gaps == [(0.49, 0.81)]
    assert check_recording(bridged) is bridged  # a listed gap is accepted as declared


def test_in_memory_stream_outside_span_is_a_warning(caplog: pytest.LogCaptureFixture) -> None:
    good = make_recording()
    late = OdometerData(t=good.odometer.t + 100, speed=good.odometer.speed)  # type: ignore[union-attr]
    with caplog.at_level(logging.WARNING, logger="fusion"):
        assert check_recording(replace(good, odometer=late)).odometer is late
    assert _warnings(caplog) == [
        "in-memory recording: Recording.odometer: lies entirely outside the IMU's time span "
        "(Recording.odometer t=100..102 s, Recording.imu t=0..2 s): none of it can be used"
    ]


def test_in_memory_truth_outside_the_imu_is_refused_as_from_a_file() -> None:
    good = make_recording()
    assert good.truth is not None
    late = replace(good, truth=replace(good.truth, t=good.truth.t + 100.0))
    assert "Recording.truth: its time span 100.0..102.0 s does not overlap Recording.imu's" in (
        _engine_problems(late)
    )
