"""Tests of fusion.recording: every reader rule of the recording format, and round trips."""

from __future__ import annotations

import gzip
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from fusion.recording import (
    FORMAT,
    ImuData,
    MagnetometerData,
    OdometerData,
    PositionData,
    Problem,
    Recording,
    RecordingError,
    RecordingMeta,
    SupportData,
    TruthData,
    UwbData,
    load_meta,
    read_recording,
    validate_recording,
    write_recording,
)

# ------------------------------------------------------------------------------------------
# A small valid recording and helpers to break it
# ------------------------------------------------------------------------------------------

META: dict[str, Any] = {
    "format": FORMAT,
    "name": "unit-test",
    "origin": {"lat_deg": 34.25, "lon_deg": 108.95, "height_m": -350.0},
    "initial": {
        "position_enu_m": [0.0, 0.0, 0.0],
        "velocity_enu_mps": [0.0, 0.0, 0.0],
        "attitude_deg": {"roll": 0.5, "pitch": -1.2, "yaw": 92.0},
        "sigma": {
            "position_m": [0.05, 0.05, 0.05],
            "velocity_mps": [0.01, 0.01, 0.01],
            "attitude_deg": [0.3, 0.3, 1.0],
        },
    },
    "imu": {
        "rate_hz": 100,
        "spec": {
            "gyro_bias_deg_h": 720,
            "gyro_arw_deg_rth": 0.6,
            "accel_bias_mg": 3,
            "accel_vrw_mg_rthz": 0.08,
        },
    },
    "odometer": {"rate_hz": 10},
    "magnetometer": {
        "rate_hz": 50,
        "declination_deg": -4.2,
        "field_uT": 50.0,
        "inclination_deg": 55.0,
    },
    "uwb": {
        "rate_hz": 10,
        "tag_lever_arm_b_m": [0.3, 0.8, 0.4],
        "anchors": {"A1": [1.112, 0.471, 1.375], "A2": [0.442, 1.483, 1.556]},
    },
    "position": {"lever_arm_b_m": [0.0, 0.0, 0.5]},
    "face": {
        "length_m": 200.0,
        "advance_m": 0.8,
        "ends_enu_m": [[0.0, 0.0, 0.0], [199.6, -2.1, 3.0]],
    },
}


def make_recording(duration: float = 2.0) -> Recording:
    """2 s at rest: IMU 100 Hz, odometer 10 Hz, magnetometer 50 Hz, UWB 2 anchors x 10 Hz."""
    rng = np.random.default_rng(1)
    n = round(duration * 100) + 1
    t = np.arange(n) * 0.01
    gyro = rng.normal(0.0, 1e-3, (n, 3))
    accel = np.array([0.0, 0.0, 9.79]) + rng.normal(0.0, 1e-2, (n, 3))
    t_odo = np.arange(0.0, duration + 1e-9, 0.1)
    t_mag = np.arange(0.0, duration + 1e-9, 0.02)
    t_uwb = np.arange(0.0, duration - 0.05 + 1e-9, 0.05)  # A1, A2 alternate: 10 Hz each
    anchor = np.arange(t_uwb.size) % 2
    t_truth = t.copy()
    cycle = np.where(t_truth < duration / 2, 0, 1)
    return Recording(
        path=None,
        meta=RecordingMeta.model_validate(META),
        imu=ImuData(t=t, gyro=gyro, accel=accel),
        odometer=OdometerData(t=t_odo, speed=np.zeros(t_odo.size)),
        magnetometer=MagnetometerData(t=t_mag, field=np.tile([20.0, 5.0, -40.0], (t_mag.size, 1))),
        uwb=UwbData(
            t=t_uwb,
            anchor_index=anchor,
            range=1.5 + 0.01 * anchor,
            anchor_ids=("A1", "A2"),
        ),
        support=SupportData(t=[0.5, 1.5], advance=[0.8, 0.8]),
        position=PositionData(t=[0.5, 1.0, 1.5], enu=np.zeros((3, 3)), sigma=np.full((3, 3), 0.02)),
        truth=TruthData(
            t=t_truth,
            position=np.zeros((n, 3)),
            velocity=np.zeros((n, 3)),
            attitude=np.tile(np.deg2rad([0.5, -1.2, 92.0]), (n, 1)),
            cycle=cycle,
        ),
    )


@pytest.fixture(scope="module")
def valid_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("template") / "rec"
    write_recording(make_recording(), root)
    return root


@pytest.fixture
def rec(valid_template: Path, tmp_path: Path) -> Path:
    """A fresh copy of the valid recording, to be broken by one test."""
    root = tmp_path / "rec"
    root.mkdir()
    for f in valid_template.iterdir():
        (root / f.name).write_bytes(f.read_bytes())
    return root


def set_line(path: Path, line: int, text: str) -> None:
    """Replace 1-based ``line`` of a text file."""
    lines = path.read_text().split("\n")
    lines[line - 1] = text
    path.write_text("\n".join(lines))


def get_line(path: Path, line: int) -> str:
    return path.read_text().split("\n")[line - 1]


def set_cell(path: Path, line: int, column: int, value: str) -> None:
    cells = get_line(path, line).split(",")
    cells[column] = value
    set_line(path, line, ",".join(cells))


def edit_meta(root: Path, change: Callable[[dict[str, Any]], None]) -> None:
    data = yaml.safe_load((root / "meta.yaml").read_text())
    change(data)
    (root / "meta.yaml").write_text(yaml.safe_dump(data, sort_keys=False))


def problems_of(root: Path, **kwargs: Any) -> list[Problem]:
    problems = validate_recording(root, **kwargs)
    with pytest.raises(RecordingError) as info:
        read_recording(root, **kwargs)
    assert info.value.problems == problems
    return problems


def only(problems: list[Problem]) -> Problem:
    assert len(problems) == 1, "\n".join(map(str, problems))
    return problems[0]


# ------------------------------------------------------------------------------------------
# Valid input
# ------------------------------------------------------------------------------------------


def test_valid_recording_reads(rec: Path) -> None:
    assert validate_recording(rec) == []
    r = read_recording(rec)
    assert r.path == rec
    assert r.imu.t.shape == (201,) and r.imu.gyro.shape == (201, 3)
    assert r.duration_s == pytest.approx(2.0)
    assert r.uwb is not None and r.uwb.anchor_ids == ("A1", "A2")
    assert r.truth is not None and r.truth.cycle.dtype == np.int64
    assert r.imu_gaps == []
    assert r.meta.magnetometer is not None and r.meta.magnetometer.declination_deg == -4.2


def test_only_required_parts(tmp_path: Path) -> None:
    full = make_recording()
    meta = full.meta.model_copy(
        update={"odometer": None, "magnetometer": None, "uwb": None, "position": None}
    )
    minimal = Recording(path=None, meta=meta, imu=full.imu)
    write_recording(minimal, tmp_path / "r")
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["imu.csv", "meta.yaml"]
    r = read_recording(tmp_path / "r")
    assert r.odometer is None and r.uwb is None and r.truth is None


def test_extra_columns_are_ignored(rec: Path) -> None:
    path = rec / "odometer.csv"
    lines = path.read_text().split("\n")
    lines = [lines[0] + ",temperature,note"] + [
        (ln + ",21.5,x y") if ln else ln for ln in lines[1:]
    ]
    path.write_text("\n".join(lines))
    assert validate_recording(rec) == []


def test_crlf_bom_and_trailing_blank_lines_accepted(rec: Path) -> None:
    path = rec / "magnetometer.csv"
    text = path.read_text()
    path.write_bytes(b"\xef\xbb\xbf" + (text + "\n\n").replace("\n", "\r\n").encode())
    assert validate_recording(rec) == []
    r = read_recording(rec)
    assert r.magnetometer is not None and r.magnetometer.t.size == 101


def test_extra_section_is_free_form(rec: Path) -> None:
    edit_meta(rec, lambda m: m.update(extra={"anything": {"goes": [1, None, "x"]}, "k": 1}))
    r = read_recording(rec)
    assert r.meta.extra["anything"] == {"goes": [1, None, "x"]}


def test_yaml_exponent_without_dot_is_a_number(rec: Path) -> None:
    text = (rec / "meta.yaml").read_text().replace("rate_hz: 100\n", "rate_hz: 1e2\n")
    (rec / "meta.yaml").write_text(text)
    assert read_recording(rec).meta.imu.rate_hz == 100.0


def test_header_only_optional_file_is_an_empty_stream(rec: Path) -> None:
    (rec / "support.csv").write_text("t,advance\n")
    r = read_recording(rec)
    assert r.support is not None and r.support.t.size == 0


# ------------------------------------------------------------------------------------------
# Missing files, meta.yaml rules
# ------------------------------------------------------------------------------------------


def test_missing_meta_yaml(rec: Path) -> None:
    (rec / "meta.yaml").unlink()
    p = only(problems_of(rec))
    assert p.file == "meta.yaml" and "required file is missing" in p.rule


def test_missing_imu_csv(rec: Path) -> None:
    (rec / "imu.csv").unlink()
    p = only(problems_of(rec))
    assert str(p) == "imu.csv: required file is missing"


def test_missing_directory(tmp_path: Path) -> None:
    p = only(problems_of(tmp_path / "nope"))
    assert "does not exist" in p.rule


def test_missing_required_key(rec: Path) -> None:
    edit_meta(rec, lambda m: m["initial"]["sigma"].pop("position_m"))
    p = only(problems_of(rec))
    assert p.file == "meta.yaml"
    assert p.where == "key initial.sigma.position_m"
    assert "required key is missing" in p.rule


def test_unknown_key_with_suggestion(rec: Path) -> None:
    edit_meta(rec, lambda m: m["imu"].update(rat_hz=100))
    p = only(problems_of(rec))
    assert p.where.startswith("key imu.rat_hz (line ")
    assert "unknown key 'rat_hz'" in p.rule and "did you mean 'rate_hz'" in p.rule


def test_unknown_key_nested_and_top_level(rec: Path) -> None:
    edit_meta(rec, lambda m: m["imu"]["spec"].update(gyro_bias_instability_deg_h=3.0))
    edit_meta(rec, lambda m: m.update(sensors={"a": 1}))
    probs = problems_of(rec)
    wheres = [p.where.split(" (")[0] for p in probs]
    assert wheres == ["key imu.spec.gyro_bias_instability_deg_h", "key sensors"]
    assert "extra" in probs[1].rule


def test_unknown_anchor_key_is_free_but_anchor_position_is_checked(rec: Path) -> None:
    edit_meta(rec, lambda m: m["uwb"]["anchors"].update(A3=[1.0, 2.0]))
    p = only(problems_of(rec))
    assert p.where.startswith("key uwb.anchors.A3")
    assert "3 numbers" in p.rule


def test_wrong_type_and_range(rec: Path) -> None:
    edit_meta(rec, lambda m: m["odometer"].update(rate_hz="fast"))
    edit_meta(rec, lambda m: m["magnetometer"].update(rate_hz=-5))
    edit_meta(rec, lambda m: m["initial"]["sigma"].update(position_m=[0.1, -0.1, 0.1]))
    probs = problems_of(rec)
    text = "\n".join(map(str, probs))
    assert "key odometer.rate_hz" in text and "must be a number (found 'fast')" in text
    assert "key magnetometer.rate_hz" in text and "must be > 0" in text
    assert "key initial.sigma.position_m[1]" in text and "must be >= 0" in text


def test_format_must_match(rec: Path) -> None:
    edit_meta(rec, lambda m: m.update(format="shearer-recording/2"))
    p = only(problems_of(rec))
    assert p.where.startswith("key format") and "shearer-recording/1" in p.rule


def test_duplicate_yaml_key(rec: Path) -> None:
    text = (rec / "meta.yaml").read_text()
    (rec / "meta.yaml").write_text(text + "name: again\n")
    p = only(problems_of(rec))
    assert p.where.startswith("key name (line ") and "duplicate key 'name'" in p.rule


def test_invalid_yaml(rec: Path) -> None:
    (rec / "meta.yaml").write_text("format: shearer-recording/1\norigin: {lat_deg: 1\n")
    p = only(problems_of(rec))
    assert p.file == "meta.yaml" and p.where.startswith("line ") and "invalid YAML" in p.rule


@pytest.mark.parametrize(
    ("stem", "section"),
    [
        ("odometer", "odometer"),
        ("magnetometer", "magnetometer"),
        ("uwb", "uwb"),
        ("position", "position"),
    ],
)
def test_csv_needs_its_section(rec: Path, stem: str, section: str) -> None:
    edit_meta(rec, lambda m: m.pop(section))
    p = only(problems_of(rec))
    assert p.file == "meta.yaml" and p.where == f"key {section}"
    assert f"{stem}.csv is present" in p.rule


def test_uwb_csv_needs_anchors(rec: Path) -> None:
    edit_meta(rec, lambda m: m["uwb"].pop("anchors"))
    p = only(problems_of(rec))
    assert p.where.startswith("key uwb.anchors") and "uwb.csv is present" in p.rule


def test_load_meta(rec: Path) -> None:
    assert load_meta(rec).name == "unit-test"
    edit_meta(rec, lambda m: m.pop("origin"))
    with pytest.raises(RecordingError, match="key origin: required key is missing"):
        load_meta(rec / "meta.yaml")


# ------------------------------------------------------------------------------------------
# CSV rules
# ------------------------------------------------------------------------------------------


def test_missing_column(rec: Path) -> None:
    set_line(rec / "imu.csv", 1, "t,wx,wy,wz,fx,fy")
    p = only(problems_of(rec))
    assert p.file == "imu.csv" and p.where == "line 1"
    assert "missing column 'fz'" in p.rule and "t,wx,wy,wz,fx,fy,fz" in p.rule


def test_columns_out_of_order(rec: Path) -> None:
    set_line(rec / "position.csv", 1, "t,n,e,u,se,sn,su")
    p = only(problems_of(rec))
    assert p.file == "position.csv" and "out of order" in p.rule


def test_headerless_file(rec: Path) -> None:
    path = rec / "odometer.csv"
    path.write_text("\n".join(path.read_text().split("\n")[1:]))
    p = only(problems_of(rec))
    assert p.where == "line 1" and "found a data row" in p.rule


def test_non_numeric_cell(rec: Path) -> None:
    set_cell(rec / "imu.csv", 17, 6, "9.8x")
    p = only(problems_of(rec))
    assert str(p).startswith("imu.csv, line 17, column fz: non-numeric value '9.8x'")


def test_decimal_comma_is_caught(rec: Path) -> None:
    """A decimal comma splits a number into two fields: a row with more fields than the header
    (``9,81`` was read as 9.0 when extra fields were ignored)."""
    set_line(rec / "odometer.csv", 5, "0.3,0,5")
    set_line(rec / "support.csv", 2, "0,5;0,8")
    odometer, support = problems_of(rec)
    assert (odometer.file, odometer.where) == ("odometer.csv", "line 5")
    assert odometer.rule.startswith("found 3 comma-separated fields, the header has 2 ('t,speed')")
    assert "decimal comma" in odometer.rule
    assert (support.file, support.where) == ("support.csv", "line 2")


def test_empty_cell(rec: Path) -> None:
    set_cell(rec / "magnetometer.csv", 4, 2, "")
    p = only(problems_of(rec))
    assert p.where == "line 4, column my" and "empty cell" in p.rule


@pytest.mark.parametrize("value", ["nan", "NaN", "inf", "-inf"])
def test_nan_or_inf(rec: Path, value: str) -> None:
    set_cell(rec / "imu.csv", 30, 2, value)
    p = only(problems_of(rec))
    assert p.file == "imu.csv" and p.where == "line 30, column wy"
    assert "not a finite number" in p.rule and "absent rows" in p.rule


def test_empty_line(rec: Path) -> None:
    set_line(rec / "imu.csv", 10, "")
    p = only(problems_of(rec))
    assert p.where == "line 10" and "empty line" in p.rule


@pytest.mark.parametrize("block_bytes", [7, 64, 1 << 23])
def test_blocks_of_any_size_read_the_same(
    rec: Path, block_bytes: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The reader streams each file in blocks of whole lines: where the blocks fall changes
    neither the values nor the line an error names (empty lines inside the file, CRLF line
    ends and trailing line ends at the end of the file included)."""
    reference = read_recording(rec)
    path = rec / "imu.csv"
    path.write_bytes(path.read_bytes().replace(b"\n", b"\r\n") + b"\r\n\n\n")
    monkeypatch.setattr("fusion.recording._BLOCK_BYTES", block_bytes)
    again = read_recording(rec)
    np.testing.assert_array_equal(again.imu.accel, reference.imu.accel)
    np.testing.assert_array_equal(again.imu.t, reference.imu.t)
    set_line(path, 10, "")
    p = only(problems_of(rec))
    assert p.where == "line 10" and "empty line" in p.rule


def test_rows_gathered_whatever_the_size_prediction(
    rec: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The rows are gathered into arrays sized from the file's length; a compressed file (length
    unknown) and a file whose first lines are longer than the rest (prediction too small) grow
    them, with the same values and line numbers."""
    reference = read_recording(rec)
    monkeypatch.setattr("fusion.recording._BLOCK_BYTES", 64)
    path = rec / "imu.csv"
    lines = path.read_bytes().split(b"\n")
    lines[1] = b"0" * 60 + lines[1]  # a long first row
    path.write_bytes(b"\n".join(lines))
    longer_first = read_recording(rec)
    (rec / "imu.csv.gz").write_bytes(gzip.compress(path.read_bytes()))
    path.unlink()
    compressed = read_recording(rec)
    for again in (longer_first, compressed):
        np.testing.assert_array_equal(again.imu.t, reference.imu.t)
        np.testing.assert_array_equal(again.imu.gyro, reference.imu.gyro)
    lines[39] = b""
    (rec / "imu.csv.gz").write_bytes(gzip.compress(b"\n".join(lines)))
    p = only(problems_of(rec))
    assert p.where == "line 40" and "empty line" in p.rule


def test_missing_fields(rec: Path) -> None:
    set_line(rec / "imu.csv", 12, "0.1,0,0")
    p = only(problems_of(rec))
    assert p.where == "line 12" and p.rule.startswith("found 3 comma-separated fields")
    assert "the header has 7" in p.rule and "decimal comma" not in p.rule


def test_time_not_increasing(rec: Path) -> None:
    path = rec / "odometer.csv"
    set_cell(path, 6, 0, "0.35")  # line 6 is t=0.4, line 7 t=0.5: now 0.3, 0.35, 0.5 ...
    set_cell(path, 8, 0, "0.35")
    p = only(problems_of(rec))
    assert p.file == "odometer.csv" and p.where == "line 8"
    assert "time must be strictly increasing (t=0.35 after t=0.5 on line 7)" in p.rule


def test_equal_times_rejected(rec: Path) -> None:
    path = rec / "imu.csv"
    set_cell(path, 50, 0, get_line(path, 49).split(",")[0])
    p = only(problems_of(rec))
    assert p.where == "line 50" and "strictly increasing" in p.rule


def test_unknown_anchor(rec: Path) -> None:
    set_cell(rec / "uwb.csv", 7, 1, "A3")
    set_cell(rec / "uwb.csv", 9, 1, "a1")
    probs = problems_of(rec)
    assert [p.where for p in probs] == ["line 7, column anchor", "line 9, column anchor"]
    assert "unknown anchor id 'A3'" in probs[0].rule and "A1, A2" in probs[0].rule
    assert "did you mean 'A1'" in probs[1].rule


def test_imu_rate_disagrees(rec: Path) -> None:
    edit_meta(rec, lambda m: m["imu"].update(rate_hz=125))
    p = only(problems_of(rec))
    assert p.file == "meta.yaml" and p.where.startswith("key imu.rate_hz")
    assert "imu.csv" in p.rule and "10%" in p.rule and "100 Hz" in p.rule


def test_rate_within_tolerance(rec: Path) -> None:
    edit_meta(rec, lambda m: m["odometer"].update(rate_hz=10.9))
    assert validate_recording(rec) == []


def test_uwb_rate_is_not_compared(rec: Path) -> None:
    # uwb.rate_hz is the nominal rate of all anchors together; which anchors answer depends on
    # where the tag is, so the file's own rate is not held against it
    edit_meta(rec, lambda m: m["uwb"].update(rate_hz=40))  # the file has 20 ranges per second
    assert validate_recording(rec) == []


def test_uwb_round_shares_a_time_stamp(rec: Path) -> None:
    path = rec / "uwb.csv"  # line k+2 is row k: A1 at even rows, A2 at odd ones, 0.05 s apart
    for line in range(3, 12, 2):  # each A2 range takes its round's A1 time stamp
        set_cell(path, line, 0, get_line(path, line - 1).split(",")[0])
    r = read_recording(rec)
    assert r.uwb is not None and np.all(np.diff(r.uwb.t) >= 0)
    assert np.count_nonzero(np.diff(r.uwb.t) == 0) == 5


def test_uwb_rows_in_time_order_per_anchor(rec: Path) -> None:
    path = rec / "uwb.csv"  # swap rows 0 and 1 (A1 at 0.0 and A2 at 0.05): A2's row first
    first, second = get_line(path, 2), get_line(path, 3)
    set_line(path, 2, second)
    set_line(path, 3, first)
    r = read_recording(rec)
    assert r.uwb is not None and np.all(np.diff(r.uwb.t) > 0)
    assert r.uwb.anchor_index[:2].tolist() == [0, 1]


def test_uwb_time_must_increase_per_anchor(rec: Path) -> None:
    path = rec / "uwb.csv"  # line 6 is A1's third range; give it A1's second range's time
    set_cell(path, 6, 0, get_line(path, 4).split(",")[0])
    p = only(problems_of(rec))
    assert p.file == "uwb.csv" and p.where == "line 6"
    assert "strictly increasing per anchor" in p.rule and "on line 4" in p.rule


def test_imu_gap_rejected_then_bridged(rec: Path) -> None:
    path = rec / "imu.csv"
    lines = path.read_text().split("\n")
    del lines[100:110]  # data lines 101..110 (t=0.99..1.08) removed
    path.write_text("\n".join(lines))
    edit_meta(rec, lambda m: m.pop("odometer"))
    (rec / "odometer.csv").unlink()
    p = only(problems_of(rec))
    assert p.file == "imu.csv" and p.where == "lines 100-101 (t=0.98..1.09 s)"
    assert "gap of 0.11 s" in p.rule and "5 sample intervals" in p.rule
    r = read_recording(rec, bridge_imu_gaps=True)
    assert r.imu_gaps == [(0.98, 1.09)]


def test_short_gap_is_not_a_gap(rec: Path) -> None:
    path = rec / "imu.csv"
    lines = path.read_text().split("\n")
    del lines[100:104]  # 4 samples missing: interval of 5 sample intervals
    path.write_text("\n".join(lines))
    assert validate_recording(rec) == []


@pytest.mark.parametrize("offset", [0.0, 1.7e9])
def test_a_gap_of_five_intervals_between_rounded_stamps_is_not_longer(
    rec: Path, offset: float
) -> None:
    """A minute at 100 Hz, its stamps written to the hundredth of a second as a logger writes
    them, with 4 samples missing at 30 s (29.99 to 30.04): the gap is 5 sample intervals, and
    the reader refused it as longer, by the rounding of the decimals (and, at Unix times, of
    the doubles)."""
    t = np.round(np.arange(6000) * 0.01, 2)
    t = np.delete(t, np.arange(3000, 3004)) + offset
    rows = [f"{x:.2f},0,0,0,0,0,9.8" for x in t]
    (rec / "imu.csv").write_text("t,wx,wy,wz,fx,fy,fz\n" + "\n".join(rows) + "\n")
    assert not [p for p in validate_recording(rec) if p.file == "imu.csv"]


def test_imu_needs_two_samples(rec: Path) -> None:
    path = rec / "imu.csv"
    path.write_text("\n".join(path.read_text().split("\n")[:2]) + "\n")
    probs = problems_of(rec)
    assert any(p.file == "imu.csv" and "at least 2 samples" in p.rule for p in probs)


def test_physical_limits(rec: Path) -> None:
    set_cell(rec / "imu.csv", 5, 3, "-51")
    set_cell(rec / "imu.csv", 6, 4, "250.5")
    set_cell(rec / "uwb.csv", 3, 2, "-0.2")
    set_cell(rec / "position.csv", 2, 6, "-0.1")
    set_cell(rec / "position.csv", 3, 5, "0")
    probs = problems_of(rec)
    text = [str(p) for p in probs]
    assert text[0].startswith("imu.csv, line 5, column wz: |wz| = 51 rad/s exceeds")
    assert text[1].startswith("imu.csv, line 6, column fx: |fx| = 250.5 m/s² exceeds")
    assert "200" in text[1]
    assert text[2].startswith("uwb.csv, line 3, column range: range must be non-negative")
    assert text[3].startswith("position.csv, line 2, column su: sigma must be positive")
    assert text[4].startswith("position.csv, line 3, column sn: sigma must be positive")
    assert len(probs) == 5


@pytest.mark.parametrize("value", ["-1", "1.5"])
def test_truth_cycle_non_negative_integer(rec: Path, value: str) -> None:
    set_cell(rec / "truth.csv", 20, 10, value)
    p = only(problems_of(rec))
    assert p.file == "truth.csv" and p.where == "line 20, column cycle"
    assert "non-negative integer" in p.rule


def test_gzip_variant_and_ambiguity(rec: Path) -> None:
    data = (rec / "odometer.csv").read_bytes()
    (rec / "odometer.csv.gz").write_bytes(gzip.compress(data))
    p = only(problems_of(rec))
    assert p.file == "odometer.csv" and "ambiguous" in p.rule
    (rec / "odometer.csv").unlink()
    r = read_recording(rec)
    assert r.odometer is not None and r.odometer.t.size == 21


def test_corrupt_gzip(rec: Path) -> None:
    (rec / "support.csv").unlink()
    (rec / "support.csv.gz").write_bytes(b"not gzip")
    p = only(problems_of(rec))
    assert p.file == "support.csv.gz" and "cannot read" in p.rule


def test_many_problems_reported_at_once(rec: Path) -> None:
    edit_meta(rec, lambda m: m["imu"].update(rat_hz=100))
    set_cell(rec / "imu.csv", 17, 6, "abc")
    set_cell(rec / "imu.csv", 40, 1, "")
    set_cell(rec / "odometer.csv", 8, 0, "0.1")
    set_cell(rec / "uwb.csv", 5, 1, "B7")
    set_cell(rec / "truth.csv", 3, 10, "-2")
    with pytest.raises(RecordingError) as info:
        read_recording(rec)
    msg = str(info.value)
    lines = msg.split("\n")
    assert lines[0].startswith(f"{rec}: 6 problems")
    assert len(lines) == 7
    for expected in (
        "meta.yaml, key imu.rat_hz",
        "imu.csv, line 17, column fz: non-numeric value 'abc'",
        "imu.csv, line 40, column wx: empty cell",
        "odometer.csv, line 8: time must be strictly increasing",
        "uwb.csv, line 5, column anchor: unknown anchor id 'B7'",
        "truth.csv, line 3, column cycle",
    ):
        assert expected in msg


def test_occurrences_capped_per_rule(rec: Path) -> None:
    path = rec / "imu.csv"
    lines = path.read_text().split("\n")
    for i in range(1, 51):
        cells = lines[i].split(",")
        cells[1] = "60"
        lines[i] = ",".join(cells)
    path.write_text("\n".join(lines))
    probs = problems_of(rec)
    assert len(probs) == 21
    assert probs[-1].file == "imu.csv" and probs[-1].rule.startswith("and 30 more occurrences")


def test_error_pickles(rec: Path) -> None:
    set_cell(rec / "imu.csv", 17, 6, "abc")
    with pytest.raises(RecordingError) as info:
        read_recording(rec)
    copy = pickle.loads(pickle.dumps(info.value))
    assert copy.problems == info.value.problems and str(copy) == str(info.value)
    assert isinstance(copy, ValueError)


# ------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------


def _same(a: Recording, b: Recording) -> None:
    assert a.meta == b.meta
    for name in ("imu", "odometer", "magnetometer", "uwb", "support", "position", "truth"):
        sa, sb = getattr(a, name), getattr(b, name)
        assert (sa is None) == (sb is None)
        if sa is None:
            continue
        for key, value in vars(sa).items():
            other = getattr(sb, key)
            if isinstance(value, np.ndarray):
                assert value.dtype == other.dtype
                np.testing.assert_array_equal(value, other)
            else:
                assert value == other


@pytest.mark.parametrize("compress", [False, True])
def test_round_trip_exact_and_deterministic(tmp_path: Path, compress: bool) -> None:
    original = make_recording()
    write_recording(original, tmp_path / "a", compress=compress)
    write_recording(original, tmp_path / "b", compress=compress)
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    suffix = ".csv.gz" if compress else ".csv"
    assert names == sorted(
        ["meta.yaml"]
        + [f"{s}{suffix}" for s in ("imu", "odometer", "magnetometer", "uwb", "support")]
        + [f"{s}{suffix}" for s in ("position", "truth")]
    )
    for name in names:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    back = read_recording(tmp_path / "a")
    _same(original, back)
    # and writing what was read gives the same bytes again
    write_recording(back, tmp_path / "c", compress=compress)
    for name in names:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "c" / name).read_bytes()


def test_writer_replaces_stale_variants(tmp_path: Path) -> None:
    original = make_recording()
    write_recording(original, tmp_path / "r", compress=True)
    write_recording(original, tmp_path / "r")
    assert not list((tmp_path / "r").glob("*.gz"))
    _same(original, read_recording(tmp_path / "r"))


def test_meta_yaml_written_readably(tmp_path: Path) -> None:
    write_recording(make_recording(), tmp_path / "r")
    text = (tmp_path / "r" / "meta.yaml").read_text()
    assert text.startswith("format: shearer-recording/1\nname: unit-test\n")
    assert "position_enu_m: [0.0, 0.0, 0.0]" in text
    assert "null" not in text


def test_writer_refuses_invalid_data(tmp_path: Path) -> None:
    good = make_recording()
    gyro = good.imu.gyro.copy()
    gyro[3, 1] = np.nan
    t = good.imu.t.copy()
    t[10] = t[9]
    bad = Recording(path=None, meta=good.meta, imu=ImuData(t=t, gyro=gyro, accel=good.imu.accel))
    with pytest.raises(RecordingError) as info:
        write_recording(bad, tmp_path / "r")
    text = str(info.value)
    assert "imu.csv, line 5, column wy: value is not a finite number" in text
    assert "imu.csv, line 12: time must be strictly increasing" in text
    assert not (tmp_path / "r").exists()
    no_section = Recording(
        path=None,
        meta=good.meta.model_copy(update={"odometer": None}),
        imu=good.imu,
        odometer=good.odometer,
    )
    with pytest.raises(RecordingError, match="section 'odometer' is required"):
        write_recording(no_section, tmp_path / "r")


def test_stream_classes_check_shapes() -> None:
    with pytest.raises(ValueError, match="gyro"):
        ImuData(t=[0.0, 0.01], gyro=np.zeros((3, 3)), accel=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="anchor_index"):
        UwbData(t=[0.0], anchor_index=[2], range=[1.0], anchor_ids=("A1",))
    with pytest.raises(ValueError, match="integer"):
        TruthData(
            t=[0.0],
            position=np.zeros((1, 3)),
            velocity=np.zeros((1, 3)),
            attitude=np.zeros((1, 3)),
            cycle=[0.5],
        )


def test_line_numbers_across_parse_blocks(rec: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import fusion.recording as recording_module

    monkeypatch.setattr(recording_module, "_BLOCK_BYTES", 300)
    path = rec / "imu.csv"
    path.write_bytes(path.read_bytes().replace(b"\n", b"\r\n"))
    assert validate_recording(rec) == []
    set_cell(path, 150, 3, "nan")
    set_cell(path, 151, 2, "?")
    set_line(path, 77, "")
    assert sorted(str(p).split(":")[0] for p in problems_of(rec)) == [
        "imu.csv, line 150, column wz",
        "imu.csv, line 151, column wy",
        "imu.csv, line 77",
    ]
