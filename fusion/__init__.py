"""shearer-fusion: longwall shearer positioning by a SINS fused with pluggable aiding sources.

The Python API: :func:`run` fuses a recording with a configuration, :func:`register_plugin`
names a plugin class defined in a script or a notebook so that a configuration can use it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fusion.config import FusionConfig
    from fusion.engine import RunResult
    from fusion.plugin import Plugin
    from fusion.recording import Recording

__version__ = "0.1.0"

__all__ = ["__version__", "register_plugin", "run"]


def run(
    config: FusionConfig | Mapping[str, Any] | str | Path,
    recording: Recording | str | Path,
    *,
    out: str | Path | None = None,
    force: bool = False,
    progress: Callable[[float], None] | None = None,
    plots: bool = False,
) -> RunResult:
    """Fuse ``recording`` with ``config`` and return the :class:`fusion.engine.RunResult`.

    Parameters
    ----------
    config
        A :class:`fusion.config.FusionConfig`, a mapping of its keys, or a YAML path (or the
        name of a shipped configuration, e.g. ``"sins_od_cpoem"``).
    recording
        A :class:`fusion.recording.Recording` or a recording directory.
    out
        When given, the result files (``solution.csv``, ``metrics.json``…, as ``fusion run``
        writes them) are written into this directory.
    force
        Replace an earlier result in ``out`` (without it, one is refused before the run);
        other files in ``out`` are left alone. The files are written whole, as ``fusion run``
        writes them (:mod:`fusion.output_dir`).
    progress
        Called during the run with the fraction done (0 to 1).
    plots
        Also draw the figures into ``out`` (when the configuration's ``output.plots`` allows).

    Raises
    ------
    fusion.config.ConfigError, fusion.recording.RecordingError, fusion.plugin.PluginError
        For a configuration, recording or plugin options that break a rule.
    fusion.output_dir.OutputRefused
        For an ``out`` that may not be written (refused before the run).
    fusion.output_dir.OutputWriteError
        When the result cannot be written (nothing is replaced).
    """
    from fusion.config import FusionConfig, find_config, load_config, parse_config
    from fusion.engine import Engine
    from fusion.output_dir import RESULT, OutputTarget
    from fusion.outputs import write_outputs
    from fusion.recording import Recording, read_recording

    if isinstance(config, FusionConfig):
        cfg = config
    elif isinstance(config, Mapping):
        cfg = parse_config(dict(config))
    else:
        cfg = load_config(find_config(config))
    target = None if out is None else OutputTarget(out, force=force, kind=RESULT)
    rec = (
        recording
        if isinstance(recording, Recording)
        else read_recording(recording, bridge_imu_gaps=cfg.bridge_imu_gaps)
    )
    result = Engine(cfg, rec).run(progress)
    if target is not None:
        with target.staging() as staging:
            write_outputs(result, rec, staging, plots=plots and cfg.output.plots)
    return result


def register_plugin(name: str, cls: type[Plugin]) -> None:
    """Make the plugin class ``cls`` usable as ``type: name`` in a configuration run in this
    process, without packaging it (see :func:`fusion.plugin.register_plugin`)."""
    from fusion.plugin import register_plugin as register

    register(name, cls)
