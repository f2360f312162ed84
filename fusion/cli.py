"""The ``fusion`` command: run, validate, validate-config, simulate, scenarios, sim-plot, import,
demo, plugins."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fusion import __version__

if TYPE_CHECKING:
    from fusion.engine import Engine
    from fusion.outputs import Invocation

_log = logging.getLogger("fusion")

EXAMPLES = """\
examples:
  fusion demo --out out/demo
      simulate the default longwall recording, fuse it, write solution, metrics and plots
  fusion scenarios
  fusion simulate longwall-200m rec/ --seed 3 --set motion.vibration=false
  fusion simulate longwall-random rec/ --seed 7 --set duration_s=900
      a random longwall world drawn from seed 7 (also longwall-random-short, -harsh)
  fusion validate rec/
  fusion import broad ../shared/datasets/broad/05_undisturbed_slow_rotation_with_breaks_B.mat rec/
  fusion run --config configs/sins_only.yaml --recording rec/ --out out/
  fusion validate-config configs/sins_only.yaml

every command takes --quiet (warnings only, no progress bars) and --verbose (debug messages)

exit statuses:
  0    success
  1    runtime failure: the engine failed, an output could not be written, the disk is full
  2    bad command-line arguments, or an output path that is refused (an existing file, a
       directory that cannot be created, an earlier result without --force)
  3    bad input: a recording, configuration, scenario or dataset breaks a rule (the message
       names the file, line or key); validate and run give 3 for the same problem
  130  interrupted (Ctrl-C)
"""

EXIT_FAILURE = 1
"""Exit status of a runtime failure: the engine failed, an output could not be written (disk
full, an I/O error); the message names the path."""
EXIT_USAGE = 2
"""Exit status for bad command-line arguments (argparse's own code) and for an output path
that is refused."""
EXIT_BAD_INPUT = 3
"""Exit status for a recording, configuration, scenario or dataset that breaks a rule (the
message names the file, line or key); ``validate`` and ``run`` give it for the same problem."""
EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT, as a shell reports it)."""

DEFAULT_DEMO_SCENARIO = "seed000-carrier"
DEFAULT_DEMO_CONFIG = "sins_od_cpoem_rts"


class _LogHandler(logging.Handler):
    """Messages of the ``fusion`` loggers on stderr, written between progress-bar redraws;
    warnings and errors say what they are."""

    def emit(self, record: logging.LogRecord) -> None:
        from tqdm import tqdm

        text = record.getMessage()
        if record.levelno >= logging.WARNING:
            text = f"{record.levelname.lower()}: {text}"
        tqdm.write(text, file=sys.stderr)


_HANDLER = _LogHandler()
_PROJECT_LOGGERS = ("fusion",)
"""The package's loggers, the bundled plugins' (``fusion.aiding.cpoem``…) among them."""


def _configure_logging(args: argparse.Namespace) -> None:
    """INFO by default, DEBUG with ``--verbose``, WARNING with ``--quiet``."""
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    for name in _PROJECT_LOGGERS:
        logger = logging.getLogger(name)
        logger.setLevel(level)
        if _HANDLER not in logger.handlers:
            logger.addHandler(_HANDLER)


@contextmanager
def _progress_bar(args: argparse.Namespace, what: str) -> Iterator[Callable[[float], None]]:
    """A tqdm bar on stderr for a long step, fed with the fraction done; drawn only on a
    terminal and never with ``--quiet``."""
    from tqdm import tqdm

    with tqdm(
        total=100,
        desc=what,
        unit="%",
        file=sys.stderr,
        disable=True if args.quiet else None,  # None: drawn on a terminal only
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
        leave=False,
    ) as bar:

        def advance(fraction: float) -> None:
            bar.update(100 * fraction - bar.n)

        yield advance


def _kernels_cached() -> bool:
    """Whether numba's on-disk cache holds the compiled kernels that every filtered run calls
    (the strapdown mechanization and the error model), so that a run starts at once; a cold
    cache costs about 30 s of compilation. Private numba attributes are read; where they are
    missing the answer is yes (nothing is announced)."""
    from numba.core.caching import FunctionCache

    from fusion import error_model, strapdown

    try:
        kernels: tuple[Any, ...] = (strapdown._advance, error_model._fill_sins_dynamics)
        for kernel in kernels:
            cache = kernel._cache
            if not isinstance(cache, FunctionCache) or not cache._cache_file._load_index():
                return False
    except AttributeError:  # another numba's internals
        return True
    return True


def _cmd_run(args: argparse.Namespace) -> int:
    from fusion.config import find_config, load_config
    from fusion.engine import Engine
    from fusion.output_dir import RESULT, OutputTarget
    from fusion.recording import read_recording

    invocation = _invocation(args)
    target = None
    if not args.check:  # a refused --out costs nothing: checked before the recording is read
        target = OutputTarget(args.out, force=args.force, kind=RESULT)
    path = find_config(args.config)
    _log.debug("configuration %s", path.resolve())
    config = load_config(path)
    recording = read_recording(args.recording, bridge_imu_gaps=config.bridge_imu_gaps)
    _log.debug(
        "recording %s: %d IMU samples over %.1f s",
        recording.path,
        recording.imu.t.size,
        float(recording.imu.t[-1] - recording.imu.t[0]),
    )
    engine = Engine(config, recording)
    if target is None:
        print(f"{args.config}: valid; states: {', '.join(engine.layout.labels)}")
        return 0
    with target.staging() as staging:
        files = _fuse_into(
            engine, staging, invocation, args, plots=not args.no_plots, figure_format=args.format
        )
    _log.info("wrote      %s", ", ".join(str(target.final(p, staging)) for p in files.values()))
    return 0


def _fuse_into(
    engine: Engine,
    out: Path,
    invocation: Invocation,
    args: argparse.Namespace,
    *,
    plots: bool,
    figure_format: str,
    recorded_as: Path | None = None,
) -> dict[str, Path]:
    """Run ``engine`` and write its result into ``out`` (a staging directory); print the
    summary unless ``--quiet``."""
    from fusion.outputs import summary, write_outputs

    recording = engine.recording
    if not _kernels_cached():
        _log.info("compiling the numerical kernels (once, ~30 s)")
    with _progress_bar(args, f"fusing {recording.meta.name or recording.path}") as progress:
        result = engine.run(progress)
    files = write_outputs(
        result,
        recording,
        out,
        plots=engine.config.output.plots and plots,
        figure_format=figure_format,
        invocation=invocation,
        recorded_as=recorded_as,
    )
    if not args.quiet:
        print(summary(result, recording))
    return files


def _invocation(args: argparse.Namespace) -> Invocation:
    """The command line and start of this command, for run.json."""
    from fusion.outputs import Invocation

    return Invocation.now(["fusion", *args.argv])


def _cmd_validate(args: argparse.Namespace) -> int:
    from fusion.recording import validate_recording

    problems = validate_recording(args.recording)
    for p in problems:
        print(str(p))
    if problems:
        print(f"{args.recording}: {len(problems)} problem(s)")
        return EXIT_BAD_INPUT
    print(f"{args.recording}: valid shearer-recording/1")
    return 0


def _cmd_validate_config(args: argparse.Namespace) -> int:
    from fusion.config import find_config, load_config
    from fusion.plugin import validate_plugin_options

    path = find_config(args.config)
    config = load_config(path)
    validate_plugin_options(config, str(path))
    print(f"{args.config}: valid ({config.name}, {len(config.plugins)} plugin(s))")
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from fusion.output_dir import RECORDING, OutputTarget
    from fusion.sim.simulate import simulate

    if args.list:
        return _cmd_scenarios(args)
    if args.scenario is None or args.out is None:
        print("error: fusion simulate: give SCENARIO and OUT (or --list)", file=sys.stderr)
        return EXIT_USAGE
    target = OutputTarget(args.out, force=args.force, kind=RECORDING)
    with target.staging() as staging, _progress_bar(args, f"simulating {args.scenario}") as bar:
        simulate(args.scenario, staging, seed=args.seed, overrides=args.set, progress=bar)
    _log.info("wrote recording %s", args.out)
    return 0


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from fusion.sim.simulate import list_scenarios

    for name, description in list_scenarios():
        print(f"{name:32s} {description}")
    return 0


def _cmd_sim_plot(args: argparse.Namespace) -> int:
    from fusion.sim.plot import plot_truth

    plot_truth(args.recording, args.out)
    _log.info("wrote %s", args.out)
    return 0


def _cmd_import(args: argparse.Namespace) -> int:
    from fusion.importers import import_dataset
    from fusion.output_dir import RECORDING, OutputTarget

    target = OutputTarget(args.out, force=args.force, kind=RECORDING)
    with target.staging() as staging:
        report = import_dataset(args.kind, args.src, staging)
    print(replace(report, out=Path(args.out)))
    print(f"{args.out}: valid shearer-recording/1")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    """Simulate into OUT/recording and fuse it into OUT/result, OUT replaced as a whole."""
    from fusion.config import find_config, load_config
    from fusion.engine import Engine
    from fusion.output_dir import DEMO, OutputTarget
    from fusion.recording import read_recording
    from fusion.sim.simulate import simulate

    invocation = _invocation(args)
    config = load_config(find_config(args.config))
    target = OutputTarget(args.out, force=args.force, kind=DEMO)
    with target.staging() as staging:
        with _progress_bar(args, f"simulating {args.scenario}") as bar:
            path = simulate(
                args.scenario,
                staging / "recording",
                seed=args.seed,
                overrides=args.set,
                progress=bar,
            )
        recording = read_recording(path, bridge_imu_gaps=config.bridge_imu_gaps)
        files = _fuse_into(
            Engine(config, recording),
            staging / "result",
            invocation,
            args,
            plots=True,
            figure_format=args.format,
            recorded_as=target.final(path, staging),
        )
    _log.info("wrote recording %s", target.final(path, staging))
    _log.info("wrote      %s", ", ".join(str(target.final(p, staging)) for p in files.values()))
    return 0


def _cmd_plugins(args: argparse.Namespace) -> int:
    from fusion.plugin import PluginError, load_plugin_class, plugin_names

    status = 0
    for name in plugin_names():
        try:
            doc = (load_plugin_class(name).__doc__ or "").strip().splitlines()
            print(f"{name:20s} {doc[0] if doc else ''}")
        except PluginError as exc:
            print(f"{name:20s} BROKEN: {exc}")
            status = EXIT_FAILURE
    return status


def _output_arguments(parser: argparse.ArgumentParser, force: str, *, figures: bool) -> None:
    """``--force`` (and ``--format`` for a command that draws figures)."""
    from fusion.output_dir import FIGURE_FORMATS

    parser.add_argument(
        "--force", action="store_true", help=f"{force} (other files there are left alone)"
    )
    if figures:
        parser.add_argument(
            "--format", choices=FIGURE_FORMATS, default="png", help="file format of the figures"
        )


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``fusion`` command."""
    from fusion.importers import IMPORTERS

    parser = argparse.ArgumentParser(
        prog="fusion",
        description="Longwall shearer positioning: SINS fused with pluggable aiding sources.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"fusion {__version__}")
    verbosity = argparse.ArgumentParser(add_help=False)
    levels = verbosity.add_mutually_exclusive_group()
    levels.add_argument(
        "-q", "--quiet", action="store_true", help="warnings and errors only, no progress bars"
    )
    levels.add_argument("-v", "--verbose", action="store_true", help="debug messages too")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", parents=[verbosity], help="fuse a recording with a configuration")
    run.add_argument("--config", required=True, help="YAML config (path or name in configs/)")
    run.add_argument("--recording", required=True, help="recording directory")
    run.add_argument("--out", required=False, default="out", help="output directory")
    run.add_argument("--check", action="store_true", help="validate config + recording only")
    run.add_argument("--no-plots", action="store_true", help="skip the figures")
    _output_arguments(run, "replace the earlier fusion result in --out", figures=True)
    run.set_defaults(func=_cmd_run)

    val = sub.add_parser(
        "validate", parents=[verbosity], help="check a recording; list every problem"
    )
    val.add_argument("recording")
    val.set_defaults(func=_cmd_validate)

    valc = sub.add_parser("validate-config", parents=[verbosity], help="check a configuration file")
    valc.add_argument("config")
    valc.set_defaults(func=_cmd_validate_config)

    sim = sub.add_parser("simulate", parents=[verbosity], help="write a simulated recording")
    sim.add_argument(
        "scenario",
        nargs="?",
        help="preset name, scenario YAML or random family (the world drawn from --seed)",
    )
    sim.add_argument("out", nargs="?", help="recording directory to write")
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scenario key (dotted path), repeatable",
    )
    sim.add_argument(
        "--list", action="store_true", help="list the scenario presets and random families"
    )
    _output_arguments(sim, "replace the recording fusion wrote in OUT", figures=False)
    sim.set_defaults(func=_cmd_simulate)

    scen = sub.add_parser(
        "scenarios", parents=[verbosity], help="list the scenario presets and random families"
    )
    scen.set_defaults(func=_cmd_scenarios)

    plot = sub.add_parser(
        "sim-plot", parents=[verbosity], help="plot a recording's truth (plan, speed, attitude)"
    )
    plot.add_argument("recording")
    plot.add_argument("out", help="PNG file")
    plot.set_defaults(func=_cmd_sim_plot)

    imp = sub.add_parser(
        "import", parents=[verbosity], help="convert a real dataset into a recording"
    )
    imp.add_argument("kind", choices=sorted(IMPORTERS))
    imp.add_argument("src", help="dataset folder (rtklib-drive) or trial .mat file")
    imp.add_argument("out", help="recording directory to write")
    _output_arguments(imp, "replace the recording fusion wrote in OUT", figures=False)
    imp.set_defaults(func=_cmd_import)

    demo = sub.add_parser(
        "demo", parents=[verbosity], help="simulate the default recording and fuse it"
    )
    demo.add_argument("--out", default="out/demo")
    demo.add_argument("--scenario", default=DEFAULT_DEMO_SCENARIO)
    demo.add_argument("--config", default=DEFAULT_DEMO_CONFIG)
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    _output_arguments(demo, "replace the earlier fusion demo in --out", figures=True)
    demo.set_defaults(func=_cmd_demo)

    plugins = sub.add_parser(
        "plugins", parents=[verbosity], help="list the registered aiding plugins"
    )
    plugins.set_defaults(func=_cmd_plugins)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``fusion`` console script: the exit status (``EXIT_*``); a user's
    error is one line on stderr, never a traceback."""
    from fusion.config import ConfigError
    from fusion.importers import DatasetError
    from fusion.output_dir import OutputRefused, OutputWriteError
    from fusion.plugin import PluginError
    from fusion.recording import RecordingError
    from fusion.sim.scenario import ScenarioError

    args = build_parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    _configure_logging(args)
    try:
        return int(args.func(args))
    except (ConfigError, RecordingError, PluginError, DatasetError, ScenarioError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OutputRefused as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except OutputWriteError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt as exc:  # its message, when there is one, says what was kept
        kept = f": {exc}" if str(exc) else ""
        print(f"fusion {args.command}: interrupted{kept}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader of stdout went away (`fusion plugins | head -1`)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # a full disk, an I/O error, a path that went away
        print(f"error: {_os_error_text(exc, getattr(args, 'out', None))}", file=sys.stderr)
        return EXIT_FAILURE


def _os_error_text(exc: OSError, out: str | Path | None) -> str:
    """``PATH: reason`` of a failed read or write: the paths the error carries or, when it
    carries none (a write that failed at close), the command's output."""
    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    reason = exc.strerror or str(exc)
    if paths:
        return f"{' -> '.join(paths)}: {reason}"
    return f"{reason} (output {out})" if out is not None else reason


if __name__ == "__main__":
    raise SystemExit(main())
