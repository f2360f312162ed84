"""shearer-fusion: longwall shearer positioning by a SINS fused with pluggable aiding sources."""

__version__ = "0.1.0"


def run(config: object, recording: object) -> object:
    """Fuse ``recording`` with ``config`` and return a :class:`fusion.engine.RunResult`.

    ``config`` is a :class:`fusion.config.FusionConfig`, a mapping, or a YAML path (or a name in
    ``configs/``); ``recording`` a :class:`fusion.recording.Recording` or a directory path.
    """
    from pathlib import Path

    from fusion.config import FusionConfig, find_config, load_config, parse_config
    from fusion.engine import Engine
    from fusion.recording import Recording, read_recording

    if isinstance(config, FusionConfig):
        cfg = config
    elif isinstance(config, dict):
        cfg = parse_config(config)
    else:
        cfg = load_config(find_config(str(config)))
    rec = recording if isinstance(recording, Recording) else read_recording(Path(str(recording)))
    return Engine(cfg, rec).run()
