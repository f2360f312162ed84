"""The documentation stays in step with what it describes: the in-repository copy of the recording
format with the shared contract, and the README with the files, modules and configurations it
names. Each test only reads text files."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
FORMAT_COPY = ROOT / "docs" / "recording-format.md"
SHARED_FORMAT = ROOT.parent / "shared" / "RECORDING_FORMAT.md"

MARKDOWN_LINK = re.compile(r"\]\(([^)\s]+)\)")


def _section(text: str, heading: str) -> str:
    """The body of the level-2 section ``## heading`` of a Markdown text."""
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.M | re.S)
    assert match is not None, f"README.md has no section '## {heading}'"
    return match.group(1)


def test_recording_format_copy_mirrors_the_shared_contract() -> None:
    """docs/recording-format.md is a one-line header, a blank line, then the shared contract's
    text unchanged (compared only where the shared directory sits beside the repository)."""
    if not SHARED_FORMAT.is_file():
        pytest.skip(f"{SHARED_FORMAT} is not beside this repository")
    header, blank, body = FORMAT_COPY.read_text(encoding="utf-8").split("\n", 2)
    assert "RECORDING_FORMAT.md" in header and blank == ""
    assert body == SHARED_FORMAT.read_text(encoding="utf-8"), (
        "docs/recording-format.md differs from ../shared/RECORDING_FORMAT.md: copy the shared"
        " text below the header line"
    )


@pytest.mark.parametrize("doc", [README, FORMAT_COPY], ids=lambda p: p.name)
def test_relative_links_resolve_inside_the_repository(doc: Path) -> None:
    """Every relative link names an existing file or directory of the repository (not one
    outside it, such as ../shared/, which a clone does not have)."""
    broken = []
    for target in MARKDOWN_LINK.findall(doc.read_text(encoding="utf-8")):
        if target.startswith(("http://", "https://", "#", "mailto:")):
            continue
        path = (doc.parent / target.split("#")[0]).resolve()
        if not (path.is_relative_to(ROOT) and path.exists()):
            broken.append(target)
    assert broken == [], f"{doc.name}: links that do not resolve inside the repository: {broken}"


def test_readme_layout_names_every_module() -> None:
    """The layout section has a line for every module of fusion/ and benchmarks/."""
    layout = _section(README.read_text(encoding="utf-8"), "Layout")
    modules = sorted(
        p.relative_to(ROOT).as_posix()
        for package in ("fusion", "benchmarks")
        for p in (ROOT / package).rglob("*.py")
    )
    missing = [m for m in modules if f"`{m}`" not in layout]
    assert missing == [], f"README.md '## Layout' lacks a line for: {missing}"


def test_readme_lists_every_shipped_configuration() -> None:
    """The configurations table has a row for every configs/*.yaml."""
    table = _section(README.read_text(encoding="utf-8"), "Configurations")
    names = sorted(p.stem for p in (ROOT / "configs").glob("*.yaml"))
    missing = [n for n in names if f"| `{n}` |" not in table]
    assert missing == [], f"README.md '## Configurations' lacks a row for: {missing}"


def test_readme_plugin_example_runs_from_yaml(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The README's worked plugin, registered the packaged way (an entry point of a throw-away
    distribution), runs in the engine from a configuration and estimates the state it owns."""
    from test_engine import make_recording

    from fusion.config import parse_config
    from fusion.engine import Engine

    section = _section(README.read_text(encoding="utf-8"), "Writing a plugin")
    code = re.search(r"```python\n(.*?)```", section, re.S)
    assert code is not None, "README.md '## Writing a plugin' has no python block"
    (tmp_path / "readme_height.py").write_text(code.group(1), encoding="utf-8")
    dist = tmp_path / "readme_example-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: readme-example\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[fusion.plugins]\nreadme_height_fix = readme_height:HeightFix\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))

    config = parse_config({"name": "readme", "plugins": [{"type": "readme_height_fix"}]})
    result = Engine(config, make_recording(3, duration=20.0)).run()
    assert len(result.innovations["readme_height_fix"].t) >= 15
    _, sigma = result.state_estimate("readme_height_fix.datum_offset")
    assert sigma[0] < 0.1  # the prior σ (offset_sigma_m): the fixes informed the owned state
