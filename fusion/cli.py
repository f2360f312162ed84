"""The ``fusion`` command: run, validate, validate-config, simulate, scenarios, sim-plot, import,
demo, plugins."""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from fusion import __version__

if TYPE_CHECKING:
    from fusion.engine import Engine
    from fusion.outputs import Invocation

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
"""

EXIT_FAILURE = 1
"""Exit status for a runtime failure: the engine failed, an output could not be written."""
EXIT_USAGE = 2
"""Exit status for bad command-line arguments (argparse's), and for an ``--out`` refused."""
EXIT_BAD_INPUT = 2
"""Exit status for a recording, configuration, scenario or dataset that breaks a rule (the
message names the file, line or key); argparse uses 2 for bad arguments as well."""
EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT, as a shell reports it)."""

DEFAULT_DEMO_SCENARIO = "seed000-carrier"
DEFAULT_DEMO_CONFIG = "sins_od_cpoem_rts"


class _Progress:
    """A one-line progress bar on stderr, shown only for runs longer than a few seconds."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.start = time.perf_counter()
        self.shown = False

    def __call__(self, fraction: float) -> None:
        elapsed = time.perf_counter() - self.start
        if not self.enabled or (elapsed < 3.0 and not self.shown):
            return
        self.shown = True
        bar = "#" * int(40 * fraction)
        eta = elapsed / max(fraction, 1e-9) - elapsed
        sys.stderr.write(f"\r[{bar:<40}] {100 * fraction:5.1f}%  eta {eta:5.0f} s")
        sys.stderr.flush()

    def close(self) -> None:
        if self.shown:
            sys.stderr.write("\n")


def _cmd_run(args: argparse.Namespace) -> int:
    from fusion.config import find_config, load_config
    from fusion.engine import Engine
    from fusion.output_dir import OutputTarget, foreign_to_result
    from fusion.recording import read_recording

    invocation = _invocation(args)
    target = None
    if not args.check:  # a refused --out costs nothing: checked before the recording is read
        target = OutputTarget(args.out, force=args.force, foreign=foreign_to_result)
    config = load_config(find_config(args.config))
    recording = read_recording(args.recording, bridge_imu_gaps=config.bridge_imu_gaps)
    engine = Engine(config, recording)
    if target is None:
        print(f"{args.config}: valid; states: {', '.join(engine.layout.labels)}")
        return 0
    with target.staging() as staging:
        files = _fuse_into(
            engine,
            staging,
            invocation,
            quiet=args.quiet,
            plots=not args.no_plots,
            figure_format=args.format,
        )
    if not args.quiet:
        print("wrote      " + ", ".join(str(target.final(p, staging)) for p in files.values()))
    return 0


def _fuse_into(
    engine: Engine,
    out: Path,
    invocation: Invocation,
    *,
    quiet: bool,
    plots: bool,
    figure_format: str,
    recorded_as: Path | None = None,
) -> dict[str, Path]:
    """Run ``engine`` and write its result into ``out`` (a staging directory); print the
    summary unless ``quiet``."""
    from fusion.outputs import summary, write_outputs

    progress = _Progress(not quiet)
    result = engine.run(progress)
    progress.close()
    files = write_outputs(
        result,
        engine.recording,
        out,
        plots=engine.config.output.plots and plots,
        figure_format=figure_format,
        invocation=invocation,
        recorded_as=recorded_as,
    )
    if not quiet:
        print(summary(result, engine.recording))
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
        return 1
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
    from fusion.output_dir import OutputTarget, foreign_to_recording
    from fusion.sim.simulate import simulate

    if args.list:
        return _cmd_scenarios(args)
    if args.scenario is None or args.out is None:
        raise SystemExit("fusion simulate: give SCENARIO and OUT (or --list)")
    target = OutputTarget(args.out, force=args.force, foreign=foreign_to_recording)
    with target.staging() as staging:
        simulate(args.scenario, staging, seed=args.seed, overrides=args.set)
    print(f"wrote recording {args.out}")
    return 0


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from fusion.sim.simulate import list_scenarios

    for name, description in list_scenarios():
        print(f"{name:32s} {description}")
    return 0


def _cmd_sim_plot(args: argparse.Namespace) -> int:
    from fusion.sim.plot import plot_truth

    plot_truth(args.recording, args.out)
    print(f"wrote {args.out}")
    return 0


def _cmd_import(args: argparse.Namespace) -> int:
    from fusion.importers import import_dataset
    from fusion.output_dir import OutputTarget, foreign_to_recording

    target = OutputTarget(args.out, force=args.force, foreign=foreign_to_recording)
    with target.staging() as staging:
        report = import_dataset(args.kind, args.src, staging)
    print(replace(report, out=Path(args.out)))
    print(f"{args.out}: valid shearer-recording/1")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    """Simulate into OUT/recording and fuse it into OUT/result, OUT replaced as a whole."""
    from fusion.config import find_config, load_config
    from fusion.engine import Engine
    from fusion.output_dir import OutputTarget, foreign_to_demo
    from fusion.recording import read_recording
    from fusion.sim.simulate import simulate

    invocation = _invocation(args)
    config = load_config(find_config(args.config))
    target = OutputTarget(args.out, force=args.force, foreign=foreign_to_demo)
    with target.staging() as staging:
        path = simulate(args.scenario, staging / "recording", seed=args.seed, overrides=args.set)
        recording = read_recording(path, bridge_imu_gaps=config.bridge_imu_gaps)
        files = _fuse_into(
            Engine(config, recording),
            staging / "result",
            invocation,
            quiet=False,
            plots=True,
            figure_format=args.format,
            recorded_as=target.final(path, staging),
        )
    print(f"wrote recording {target.final(path, staging)}")
    print("wrote      " + ", ".join(str(target.final(p, staging)) for p in files.values()))
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
            status = 1
    return status


def _output_arguments(parser: argparse.ArgumentParser, force: str, *, figures: bool) -> None:
    """``--force`` (and ``--format`` for a command that draws figures)."""
    from fusion.output_dir import FIGURE_FORMATS

    parser.add_argument(
        "--force", action="store_true", help=f"{force} (never a directory of other files)"
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
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="fuse a recording with a configuration")
    run.add_argument("--config", required=True, help="YAML config (path or name in configs/)")
    run.add_argument("--recording", required=True, help="recording directory")
    run.add_argument("--out", required=False, default="out", help="output directory")
    run.add_argument("--check", action="store_true", help="validate config + recording only")
    run.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    run.add_argument("--no-plots", action="store_true", help="skip the figures")
    _output_arguments(run, "replace the earlier fusion result in --out", figures=True)
    run.set_defaults(func=_cmd_run)

    val = sub.add_parser("validate", help="check a recording; list every problem")
    val.add_argument("recording")
    val.set_defaults(func=_cmd_validate)

    valc = sub.add_parser("validate-config", help="check a configuration file")
    valc.add_argument("config")
    valc.set_defaults(func=_cmd_validate_config)

    sim = sub.add_parser("simulate", help="write a simulated recording")
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

    scen = sub.add_parser("scenarios", help="list the scenario presets and random families")
    scen.set_defaults(func=_cmd_scenarios)

    plot = sub.add_parser("sim-plot", help="plot a recording's truth (plan, speed, attitude)")
    plot.add_argument("recording")
    plot.add_argument("out", help="PNG file")
    plot.set_defaults(func=_cmd_sim_plot)

    imp = sub.add_parser("import", help="convert a real dataset into a recording")
    imp.add_argument("kind", choices=sorted(IMPORTERS))
    imp.add_argument("src", help="dataset folder (rtklib-drive) or trial .mat file")
    imp.add_argument("out", help="recording directory to write")
    _output_arguments(imp, "replace the recording fusion wrote in OUT", figures=False)
    imp.set_defaults(func=_cmd_import)

    demo = sub.add_parser("demo", help="simulate the default recording and fuse it")
    demo.add_argument("--out", default="out/demo")
    demo.add_argument("--scenario", default=DEFAULT_DEMO_SCENARIO)
    demo.add_argument("--config", default=DEFAULT_DEMO_CONFIG)
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    _output_arguments(demo, "replace the earlier fusion demo in --out", figures=True)
    demo.set_defaults(func=_cmd_demo)

    plugins = sub.add_parser("plugins", help="list the registered aiding plugins")
    plugins.set_defaults(func=_cmd_plugins)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``fusion`` console script."""
    from fusion.config import ConfigError
    from fusion.importers import DatasetError
    from fusion.output_dir import OutputRefused, OutputWriteError
    from fusion.plugin import PluginError
    from fusion.recording import RecordingError
    from fusion.sim.scenario import ScenarioError

    args = build_parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
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


if __name__ == "__main__":
    raise SystemExit(main())
