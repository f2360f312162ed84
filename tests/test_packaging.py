"""Packaging (issue 30): configurations found by name from any directory, numba kernels that
compile without an on-disk cache where numba has nowhere to write one, and a wheel that holds
the configurations, the scenarios and every module, and works installed."""

from __future__ import annotations

import importlib.util
import logging
import os
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import numba
import pytest

from fusion import kernels
from fusion.config import PACKAGED_CONFIGS, find_config, load_config

REPO = Path(__file__).resolve().parents[1]


def test_configs_are_found_by_name_from_any_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    packaged = PACKAGED_CONFIGS / "sins_od_cpoem.yaml"
    for given in ("sins_od_cpoem", "sins_od_cpoem.yaml", "configs/sins_od_cpoem.yaml"):
        assert find_config(given) == packaged
    # its imu.file (configs/imu/spec-relative.yaml) is read beside it
    assert load_config(find_config("sins_od_cpoem")).imu.bias_instability_fraction == 0.0225


def test_a_path_as_given_then_the_working_directory_then_the_packaged_configs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "sins_only.yaml").write_text("name: local\n")
    (tmp_path / "sins_only").write_text("name: as given\n")
    assert find_config("sins_only") == Path("sins_only")
    assert find_config("sins_only.yaml") == Path("configs/sins_only.yaml")
    assert find_config("sins_mc") == PACKAGED_CONFIGS / "sins_mc.yaml"
    # A path in any other directory is never replaced by a packaged config of the same name.
    assert find_config("elsewhere/sins_only.yaml") == Path("elsewhere/sins_only.yaml")
    assert find_config("no_such_config") == Path("no_such_config")


def _kernel_source(directory: Path) -> tuple[Callable[..., float], Callable[..., float]]:
    """Two plain functions defined in a module file of ``directory``."""
    directory.mkdir()
    source = directory / "kernel_source.py"
    source.write_text("def double(x):\n    return 2.0 * x\n\n\ndef square(x):\n    return x * x\n")
    spec = importlib.util.spec_from_file_location(f"kernel_source_{directory.name}", source)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.double, module.square


def test_kernels_are_cached_beside_their_source_where_it_is_writable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    double, _ = _kernel_source(tmp_path / "writable")
    assert kernels.jit(double)(1.5) == 3.0
    assert list((tmp_path / "writable" / "__pycache__").glob("kernel_source.double-*.nbi"))
    assert not caplog.records


def test_kernels_compile_without_a_cache_and_warn_once_where_numba_has_no_locator(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A read-only site-packages and no writable HOME, as root: every place numba would cache in
    (NUMBA_CACHE_DIR, the __pycache__ beside the source, the user cache directory) is a path
    that cannot be created because a regular file stands in its way."""
    double, square = _kernel_source(tmp_path / "site")
    (tmp_path / "site" / "__pycache__").write_text("")
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(blocker / "numba"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker / "cache"))
    with pytest.raises(RuntimeError, match="no locator available"):
        numba.njit(cache=True)(double)

    with caplog.at_level(logging.WARNING, logger="fusion"):
        assert kernels.jit(double)(1.5) == 3.0
        assert kernels.jit(square)(3.0) == 9.0
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    assert "cannot cache" in caplog.text and str(tmp_path / "site") in caplog.text


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The project's wheel, built from a copy of the sources (a build in the clone would leave
    build/ there, whose stale files later builds pick up)."""
    root = tmp_path_factory.mktemp("wheel")
    source = root / "source"
    ignore = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc")
    for name in ("fusion", "configs"):
        shutil.copytree(REPO / name, source / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    pip_wheel = [sys.executable, "-m", "pip", "wheel", str(source), "--wheel-dir", str(root)]
    offline = ["--no-deps", "--no-build-isolation", "--no-index", "--quiet"]
    built = subprocess.run([*pip_wheel, *offline], capture_output=True, text=True)
    assert built.returncode == 0, built.stderr  # e.g. setuptools < 77: pip install -e '.[test]'
    (path,) = root.glob("shearer_fusion-*.whl")
    return path


@pytest.mark.slow
def test_the_wheel_holds_the_configs_the_scenarios_and_every_module(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    configs = [p.relative_to(REPO / "configs") for p in (REPO / "configs").rglob("*.yaml")]
    assert {p for p in configs if p.parent == Path("imu")}, "configs/imu/ has no file"
    for p in configs:
        assert f"fusion/configs/{p.as_posix()}" in names
    for p in (REPO / "fusion" / "sim" / "scenarios").glob("*.yaml"):
        assert f"fusion/sim/scenarios/{p.name}" in names
    for p in (REPO / "fusion").rglob("*.py"):
        assert p.relative_to(REPO).as_posix() in names, f"{p} is not in the wheel"
    assert "fusion/py.typed" in names
    (metadata,) = {n.split("/")[0] for n in names} - {"fusion"}  # one top-level package
    assert metadata.endswith(".dist-info")


@pytest.mark.slow
def test_installed_it_finds_its_configs_anywhere_and_runs_without_a_cache_locator(
    wheel: Path, tmp_path: Path
) -> None:
    """The wheel unpacked as site-packages, numba's three cache places blocked as above; the
    scorer's command line from a directory without configs/."""
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    (site / "fusion" / "__pycache__").write_text("")
    (tmp_path / "blocker").write_text("")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env |= {"PYTHONPATH": str(site), "HOME": str(tmp_path / "blocker" / "home")}
    env |= {"XDG_CACHE_HOME": str(tmp_path / "blocker" / "cache")}
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "blocker" / "numba")
    (tmp_path / "work").mkdir()
    code = (
        "import fusion, fusion.kalman, fusion.screening, fusion.strapdown\n"
        "from fusion.cli import main\n"
        "print(fusion.__file__)\n"
        "raise SystemExit(main(['validate-config', 'configs/sins_od_cpoem.yaml']))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path / "work",
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[0] == str(site / "fusion" / "__init__.py")
    assert "configs/sins_od_cpoem.yaml: valid" in proc.stdout
    assert "Traceback" not in proc.stderr
    assert [line for line in proc.stderr.splitlines() if line] == [
        line for line in proc.stderr.splitlines() if "numba cannot cache" in line
    ]
    assert proc.stderr.count("numba cannot cache") == 1
