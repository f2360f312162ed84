"""The Python API: ``fusion.run`` with progress and an output directory, configuration models
that validate assignments, and plugins registered at run time."""

from __future__ import annotations

import inspect
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel, ValidationError

import fusion
import fusion.plugin
from fusion.config import FusionConfig, parse_config
from fusion.output_dir import OutputRefused
from fusion.plugin import Plugin, PluginError
from fusion.validation import allowed_interval

EXAMPLES = Path(__file__).resolve().parent / "example_plugins"


@pytest.fixture
def registry(monkeypatch: pytest.MonkeyPatch) -> None:
    """Run-time registrations of a test stay in that test."""
    monkeypatch.setattr(fusion.plugin, "_registered_at_run_time", {})


def test_run_reports_progress_and_writes_only_where_allowed(
    tmp_path: Path, registry: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A plugin defined here, in a script, is named in a config after ``register_plugin``."""
    from test_engine import make_recording

    monkeypatch.syspath_prepend(str(EXAMPLES))
    from height_fix import HeightFix

    class ScriptHeight(HeightFix):
        """Not packaged: no entry point names it."""

    fusion.register_plugin("script_height", ScriptHeight)
    recording = make_recording(2, duration=10.0)
    config = {"name": "script", "plugins": [{"type": "script_height"}]}
    done: list[float] = []
    result = fusion.run(config, recording, out=tmp_path / "res", progress=done.append)
    assert result.innovations["script_height"].count >= 8  # 1-Hz fixes over 10 s
    assert done == sorted(done) and 0.99 <= done[-1] <= 1.0 and len(done) > 10
    written = {p.name for p in (tmp_path / "res").iterdir()}
    assert "solution.csv" in written and not any(n.endswith(".png") for n in written)
    with pytest.raises(OutputRefused, match="holds an earlier result"):
        fusion.run(config, recording, out=tmp_path / "res")
    (tmp_path / "res" / "solution.csv").unlink()
    fusion.run(config, recording, out=tmp_path / "res", force=True)
    assert (tmp_path / "res" / "solution.csv").exists()


def test_run_is_typed_for_editors_and_mypy() -> None:
    """The annotations name the real classes (imported for type checkers only, so that
    ``import fusion`` stays light); the options are keyword-only."""
    from fusion.engine import RunResult
    from fusion.plugin import Plugin
    from fusion.recording import Recording

    names = {"FusionConfig": FusionConfig, "RunResult": RunResult, "Recording": Recording}
    hints = typing.get_type_hints(fusion.run, localns=names)
    assert hints["return"] is RunResult
    assert FusionConfig in typing.get_args(hints["config"])
    assert Recording in typing.get_args(hints["recording"])
    options = inspect.signature(fusion.run).parameters
    assert all(options[n].kind is inspect.Parameter.KEYWORD_ONLY for n in ("out", "progress"))
    hints = typing.get_type_hints(fusion.register_plugin, localns={"Plugin": Plugin})
    assert hints["cls"] == type[Plugin]


def test_register_plugin_refuses_what_it_cannot_use(registry: None) -> None:
    with pytest.raises(PluginError, match=r"is not a fusion\.plugin\.Plugin"):
        fusion.register_plugin("thing", dict)  # type: ignore[arg-type]
    with pytest.raises(PluginError, match="'odometer' is already the installed plugin"):
        fusion.register_plugin("odometer", Plugin)
    with pytest.raises(PluginError, match="without spaces"):
        fusion.register_plugin("two words", Plugin)
    assert "thing" not in fusion.plugin.plugin_names()


def test_config_assignments_are_validated() -> None:
    config = parse_config({"name": "c"})
    with pytest.raises(ValidationError, match="covariance_step_s"):
        config.filter.covariance_step_s = -1.0
    with pytest.raises(ValidationError, match="rate_hz"):
        config.output.rate_hz = float("inf")
    config.filter.covariance_step_s = 0.05
    assert config.filter.covariance_step_s == 0.05
    assert parse_config({"name": "c"}).filter.covariance_step_s == 0.1  # defaults untouched


def _numeric_fields(model: type[BaseModel]) -> typing.Iterator[tuple[type[BaseModel], str]]:
    for name, info in model.model_fields.items():
        args = typing.get_args(info.annotation) or (info.annotation,)
        if any(isinstance(a, type) and issubclass(a, BaseModel) for a in args):
            yield from _numeric_fields(next(a for a in args if isinstance(a, type)))
        elif (float in args or int in args) and bool not in args:
            yield model, name


def test_every_numeric_config_field_states_the_range_it_enforces() -> None:
    fields = list(_numeric_fields(FusionConfig))
    assert len(fields) > 50
    for model, name in fields:
        interval = allowed_interval(model, [name])
        description = model.model_fields[name].description or ""
        assert interval is not None and "inf" not in interval, (model.__name__, name)
        assert f"allowed {interval}" in description, (model.__name__, name, description)


def test_the_simulator_reports_its_progress_per_chunk(tmp_path: Path) -> None:
    from fusion.sim.simulate import simulate

    done: list[float] = []
    overrides = ["duration_s=10", "chunk_s=2.5"]
    simulate(
        "longwall-random-short", tmp_path / "rec", seed=1, overrides=overrides, progress=done.append
    )
    assert len(done) >= 4 and done == sorted(done) and done[-1] == 1.0
