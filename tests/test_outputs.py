"""What ``fusion run`` leaves in ``--out``: complete results only, replaced whole, with their
``run.json``; a killed or interrupted run leaves the earlier result or nothing."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import signal
from collections.abc import Callable
from dataclasses import replace
from datetime import datetime
from pathlib import Path
from typing import Any

import matplotlib
import pytest

import fusion.outputs
from fusion import __version__
from fusion.cli import EXIT_INTERRUPTED, EXIT_USAGE, main
from fusion.config import FusionConfig, parse_config
from fusion.engine import Engine, RunResult
from fusion.output_dir import DEMO, RECORDING, RESULT, OutputRefused, OutputTarget
from fusion.outputs import write_outputs
from fusion.recording import Recording, read_recording, write_recording
from tests.test_engine import make_recording

CONFIG = {"name": "fixes_rts", "plugins": [{"type": "position"}], "smoother": {"mode": "whole"}}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 12-s recording with truth and 1-Hz fixes on disk, and a smoothing config file."""
    root = tmp_path_factory.mktemp("inputs")
    write_recording(make_recording(1, 12.0), root / "rec")
    (root / "config.yaml").write_text(parse_config(CONFIG).to_yaml(), encoding="utf-8")
    return root / "rec", root / "config.yaml"


@pytest.fixture(scope="module")
def run(inputs: tuple[Path, Path]) -> tuple[RunResult, Recording]:
    recording = read_recording(inputs[0])
    return Engine(parse_config(CONFIG), recording).run(), recording


def _fusion_run(inputs: tuple[Path, Path], out: Path, *extra: str) -> int:
    rec, config = inputs
    argv = ["run", "--config", str(config), "--recording", str(rec), "--out", str(out)]
    return main([*argv, "--quiet", "--no-plots", *extra])


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _complete(out: Path) -> dict[str, Any]:
    """The run.json of ``out`` after checking that it lists exactly the other files, each
    whole (size and digest as written)."""
    record = json.loads((out / "run.json").read_text())
    assert sorted(os.listdir(out)) == sorted([*record["files"], "run.json"])
    for name, entry in record["files"].items():
        assert (out / name).stat().st_size == entry["bytes"] > 0, name
        assert _sha256(out / name) == entry["sha256"], name
    return record


def _hidden_beside(out: Path) -> list[str]:
    return sorted(p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}."))


def test_run_json_records_config_version_recording_command_times_and_files(
    inputs: tuple[Path, Path], tmp_path: Path
) -> None:
    out = tmp_path / "out"
    out.mkdir()  # an existing empty directory is fine
    before = datetime.now().astimezone()
    assert _fusion_run(inputs, out) == 0
    record = _complete(out)
    assert set(record["files"]) == {"solution.csv", "smoothed.csv", "states.csv", "metrics.json"}
    assert record["fusion_version"] == __version__
    assert record["command"][:2] == ["fusion", "run"] and str(out) in record["command"]
    started = datetime.fromisoformat(record["started_utc"])
    assert started.utcoffset() is not None and started.utcoffset().total_seconds() == 0
    assert 0 <= (started - before).total_seconds() < 60
    assert 0 < record["engine_wall_time_s"] <= record["wall_time_s"]
    assert record["config"] == FusionConfig.model_validate(CONFIG).model_dump(mode="json")
    assert record["config"]["smoother"]["memory_budget_mb"] == 256.0  # defaults filled in
    rec = record["recording"]
    assert rec["path"] == str(inputs[0].resolve())
    names = sorted(os.listdir(inputs[0]))
    assert sorted(rec["files"]) == names
    assert all(rec["files"][n] == _sha256(inputs[0] / n) for n in names)
    listing = "".join(f"{rec['files'][n]}  {n}\n" for n in names)  # as `sha256sum` prints it
    assert rec["sha256"] == hashlib.sha256(listing.encode()).hexdigest()
    assert _hidden_beside(out) == []


def test_a_second_run_is_refused_and_force_replaces_only_a_fusion_result(
    inputs: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert _fusion_run(inputs, out) == 0
    first = _complete(out)
    capsys.readouterr()
    assert _fusion_run(inputs, out) == EXIT_USAGE
    err = capsys.readouterr().err
    assert err == f"error: {out}: holds an earlier result; give --force to replace it\n"
    assert _complete(out) == first  # untouched

    (out / "plan.png").write_bytes(b"from a run before run.json existed")  # not listed
    assert _fusion_run(inputs, out, "--force") == EXIT_USAGE
    err = capsys.readouterr().err
    assert "'plan.png', which fusion did not write and would overwrite" in err
    (out / "plan.png").unlink()

    (out / "faults.csv").write_text("time_s\n")  # an earlier result's extra file, listed
    first["files"]["faults.csv"] = {"bytes": 7, "sha256": _sha256(out / "faults.csv")}
    (out / "run.json").write_text(json.dumps(first))
    assert _fusion_run(inputs, out, "--force") == 0
    second = _complete(out)  # the stale faults.csv is gone with the rest of the earlier result
    assert second["started_utc"] > first["started_utc"] and "faults.csv" not in second["files"]
    assert _hidden_beside(out) == []

    (tmp_path / "file").write_text("")
    assert _fusion_run(inputs, tmp_path / "file", "--force") == EXIT_USAGE
    assert "exists and is not a directory" in capsys.readouterr().err


@pytest.mark.parametrize(
    "command", [["simulate", "longwall-random-short"], ["import", "broad", "nope.mat"]]
)
def test_recording_directories_are_refused_the_same_way(
    command: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Refused before any work: an earlier recording without --force, and a file fusion did not
    write under a recording file's name (no meta.yaml beside it) even with --force."""
    out = tmp_path / "rec"
    out.mkdir()
    (out / "meta.yaml").write_text("mine")
    assert main([*command, str(out)]) == EXIT_USAGE
    assert "holds an earlier recording; give --force" in capsys.readouterr().err
    (out / "meta.yaml").rename(out / "notes.yaml")
    (out / "imu.csv").write_text("mine")
    assert main([*command, str(out), "--force"]) == EXIT_USAGE
    assert "'imu.csv', which fusion did not write" in capsys.readouterr().err
    assert sorted(os.listdir(out)) == ["imu.csv", "notes.yaml"]
    assert RECORDING.earlier(out) == frozenset()


def test_a_demo_directory_is_recognised_by_its_recording_and_result(tmp_path: Path) -> None:
    demo = tmp_path / "demo"
    (demo / "recording").mkdir(parents=True)
    (demo / "recording" / "meta.yaml").write_text("")
    (demo / "recording" / "imu.csv").write_text("")
    (demo / "result").mkdir()
    (demo / "result" / "run.json").write_text('{"files": ["solution.csv"]}')
    (demo / "result" / "solution.csv").write_text("")
    (demo / "README").write_text("")  # the caller's: left alone
    assert DEMO.earlier(demo) == {"recording", "result"}
    (demo / "result" / "extra.png").write_text("")  # result/ is no longer only a result
    assert DEMO.earlier(demo) == {"recording"}
    with pytest.raises(OutputRefused, match="holds 'result', which fusion did not write"):
        OutputTarget(demo, force=True, kind=DEMO)


def test_a_directory_of_other_files_gets_the_result_beside_them(
    run: tuple[RunResult, Recording], tmp_path: Path
) -> None:
    """A caller's log redirected into --out before the run: written beside, never touched; a
    second run then needs --force and replaces the result, the log still untouched."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "stdout.log").write_text("the caller's")
    target = OutputTarget(out, force=False, kind=RESULT)
    with target.staging() as staging:
        write_outputs(*run, staging, plots=False)
    record = json.loads((out / "run.json").read_text())
    assert sorted(os.listdir(out)) == sorted([*record["files"], "run.json", "stdout.log"])
    with pytest.raises(OutputRefused, match="holds an earlier result"):
        OutputTarget(out, force=False, kind=RESULT)
    _publish(run, out)
    assert json.loads((out / "run.json").read_text())["started_utc"] != record["started_utc"]
    assert (out / "stdout.log").read_text() == "the caller's"
    assert _hidden_beside(out) == []


def test_figures_in_the_format_asked_and_errors_draw_the_smoothed_track(
    run: tuple[RunResult, Recording], tmp_path: Path
) -> None:
    result, recording = run
    assert result.smoothed is not None
    with pytest.raises(ValueError, match="'gif': not one of png, svg, pdf"):
        write_outputs(result, recording, tmp_path / "gif", figure_format="gif")
    assert not (tmp_path / "gif").exists()  # refused before anything is written
    without_observability = replace(result, observability=None)  # two figures are enough
    with matplotlib.rc_context({"svg.fonttype": "none"}):  # labels as text, to be read back
        files = write_outputs(without_observability, recording, tmp_path, figure_format="svg")
    assert (files["plan"].name, files["errors"].name) == ("plan.svg", "errors.svg")
    assert {"plan.svg", "errors.svg"} <= set(json.loads(files["run"].read_text())["files"])
    text = files["errors"].read_text()
    assert text.startswith("<?xml") and "<svg" in text
    assert "forward error" in text and "smoothed error" in text and "smoothed ±3σ" in text


# ------------------------------------------------------------------------------------------
# A run killed or interrupted while it writes
# ------------------------------------------------------------------------------------------


def _publish(run: tuple[RunResult, Recording], out: Path) -> None:
    """What ``fusion run --force`` does once the engine is done."""
    target = OutputTarget(out, force=True, kind=RESULT)
    with target.staging() as staging:
        write_outputs(*run, staging, plots=False)


def _kill_self() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _cut_solution_then_kill(real: Callable[..., None]) -> Callable[..., None]:
    def write(solution: Any, path: Path) -> None:
        real(solution, path)
        with open(path, "r+b") as f:
            f.truncate(path.stat().st_size // 2)
        _kill_self()

    return write


def _kill_at_call(n: int, real: Callable[..., Any]) -> Callable[..., Any]:
    calls = iter(range(1, 1_000))

    def call(*args: Any, **kwargs: Any) -> Any:
        if next(calls) == n:
            _kill_self()
        return real(*args, **kwargs)

    return call


KILL_POINTS: dict[str, Callable[[], None]] = {
    "while solution.csv is half written": lambda: setattr(
        fusion.outputs, "write_solution", _cut_solution_then_kill(fusion.outputs.write_solution)
    ),
    "just before the swap": lambda: setattr(os, "rename", _kill_at_call(1, os.rename)),
    "with the earlier result moved aside": lambda: setattr(
        os, "rename", _kill_at_call(2, os.rename)
    ),
    "after the swap, before the earlier result is deleted": lambda: setattr(
        shutil, "rmtree", _kill_at_call(1, shutil.rmtree)
    ),
}


def _killed_while_publishing(run: tuple[RunResult, Recording], out: Path, point: str) -> None:
    """Publish in a forked child process that SIGKILLs itself at ``point``."""
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            KILL_POINTS[point]()
            _publish(run, out)
        finally:
            os._exit(3)
    _, status = os.waitpid(pid, 0)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL, point


@pytest.fixture
def earlier(run: tuple[RunResult, Recording], tmp_path: Path) -> Path:
    out = tmp_path / "out"
    _publish(run, out)
    return out


@pytest.mark.parametrize("point", list(KILL_POINTS))
def test_a_run_killed_while_writing_leaves_the_earlier_result_or_nothing(
    run: tuple[RunResult, Recording], earlier: Path, point: str
) -> None:
    before = _complete(earlier)
    _killed_while_publishing(run, earlier, point)
    if earlier.exists():  # never a mix, never a cut file under a current name
        after = _complete(earlier)
        new = point.startswith("after the swap")
        assert (after["started_utc"] != before["started_utc"]) == new, point
    else:
        assert point == "with the earlier result moved aside"
    assert _hidden_beside(earlier)  # the dead run's staging (or the earlier result) aside
    _publish(run, earlier)  # the next run deletes what the killed one left
    _complete(earlier)
    assert _hidden_beside(earlier) == []


def test_a_first_run_killed_while_writing_leaves_nothing(
    run: tuple[RunResult, Recording], tmp_path: Path
) -> None:
    out = tmp_path / "out"
    _killed_while_publishing(run, out, "while solution.csv is half written")
    assert not out.exists()


@pytest.mark.parametrize("has_earlier", [True, False])
def test_ctrl_c_while_writing_says_what_was_kept(
    inputs: tuple[Path, Path],
    tmp_path: Path,
    has_earlier: bool,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "out"
    if has_earlier:
        assert _fusion_run(inputs, out) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()} if has_earlier else None
    real = fusion.outputs.write_solution

    def write_then_ctrl_c(solution: Any, path: Path) -> None:
        real(solution, path)
        signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(fusion.outputs, "write_solution", write_then_ctrl_c)
    # Python's own handler even where the test runner inherited SIGINT ignored (a background
    # job of a shell without job control).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        capsys.readouterr()
        status = _fusion_run(inputs, out, "--force")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert status == EXIT_INTERRUPTED
    err = capsys.readouterr().err
    kept = "still holds the earlier result" if has_earlier else "unchanged (no earlier result)"
    assert err == f"fusion run: interrupted: nothing written; {out} {kept}\n"
    if has_earlier:
        assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    else:
        assert not out.exists()
    assert _hidden_beside(out) == []


# ------------------------------------------------------------------------------------------
# A target no rename can replace (a container's output volume)
# ------------------------------------------------------------------------------------------


def _refuse_directory_renames(code: int, real: Callable[..., None]) -> Callable[..., None]:
    """``os.rename`` as on a mount point: a directory cannot be renamed onto or off it."""

    def rename(src: Any, dst: Any, *args: Any, **kwargs: Any) -> None:
        if Path(src).is_dir():
            raise OSError(code, os.strerror(code), str(src))
        real(src, dst, *args, **kwargs)

    return rename


@pytest.mark.parametrize("code", ["EXDEV", "EBUSY"])
def test_a_mount_point_target_gets_the_files_moved_in(
    run: tuple[RunResult, Recording],
    earlier: Path,
    code: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    before = _complete(earlier)["started_utc"]
    monkeypatch.setattr(os, "rename", _refuse_directory_renames(getattr(errno, code), os.rename))
    _publish(run, earlier)  # replaces the earlier result file by file
    assert _complete(earlier)["started_utc"] != before
    assert _hidden_beside(earlier) == []


def test_an_unwritable_parent_stages_inside_the_target(
    run: tuple[RunResult, Recording],
    earlier: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    dead = earlier / ".fusion-staging-999999999"  # a killed run's, inside: ignored, then deleted
    dead.mkdir()
    OutputTarget(earlier, force=True, kind=RESULT)  # not refused
    real = Path.mkdir

    def mkdir(self: Path, *args: Any, **kwargs: Any) -> None:
        if self.parent == earlier.parent and self != earlier:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    _publish(run, earlier)
    _complete(earlier)  # run.json lists exactly the files: no staging directory is left
    assert _hidden_beside(earlier) == []
