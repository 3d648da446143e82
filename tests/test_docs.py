"""The manual runs: every Python example of the README and of docs/ runs as written (each page
as one script, its blocks in order, from a directory that looks like the repository root),
every `tendonsense ...` command shown parses and names files that exist, and every link
points inside the repository."""

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: files that the examples themselves write before another example reads them
WRITTEN = {"fitted.toml", "estimates.csv", "live.csv", "solve.png", "estimate.png", "motion.csv",
           "step.csv", "short.toml"}


def python_blocks(page: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", page.read_text(), re.S | re.M)


def shell_commands(page: Path) -> list[str]:
    out = []
    for block in re.findall(r"^```sh\n(.*?)^```", page.read_text(), re.S | re.M):
        for line in block.replace("\\\n", " ").splitlines():
            for part in re.split(r"&&|\|", line):
                part = part.split(">")[0].strip()
                if part.startswith("tendonsense "):
                    out.append(part)
    return out


def test_manual_has_pages():
    assert len(PAGES) - 1 >= 4
    assert sum(len(python_blocks(p)) for p in PAGES) >= 5


@pytest.mark.parametrize("page", [p for p in PAGES if python_blocks(p)],
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_python_examples_run(page, tmp_path):
    """A page's Python blocks, in order, as one script; the working directory holds
    ``examples/`` (a link to the repository's), so files the examples write go elsewhere."""
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    # a guard against a hang, not a speed check: from an empty cache the Python page compiles
    # about 15 programs (486 s with two test workers on 2 cores)
    p = subprocess.run([sys.executable, "-c", "\n".join(python_blocks(page))], cwd=tmp_path,
                       capture_output=True, text=True, timeout=1500)
    assert p.returncode == 0, p.stderr[-3000:]


@pytest.mark.parametrize("page", [p for p in PAGES if shell_commands(p)],
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_shell_commands_parse(page):
    """Every `tendonsense` command shown is valid usage, and its input files exist."""
    from tendonsense.cli import build_parser
    parser = build_parser()
    for command in shell_commands(page):
        args = parser.parse_args(shlex.split(command)[1:])
        for name in ("robot", "robot_option", "readings", "snapshots", "csv", "sets",
                     "tensions"):
            values = getattr(args, name, None)
            for value in values if isinstance(values, list) else [values]:
                if value and value != "-" and Path(value).name not in WRITTEN:
                    found = (Path(value).exists() if Path(value).is_absolute()
                             else list(ROOT.glob(value)))
                    assert found, f"{page.name}: {command}: no file {value}"


LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_links_stay_in_the_repository(page):
    for target in LINK.findall(page.read_text()):
        assert "://" not in target and not target.startswith("/"), f"{page.name}: {target}"
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        assert dest.is_relative_to(ROOT), f"{page.name}: {target} leaves the repository"
        assert dest.exists(), f"{page.name}: {target} does not exist"
        if anchor and dest.suffix == ".md":
            assert anchor in anchors(dest), f"{page.name}: {target}: no such heading"


def anchors(page: Path) -> set[str]:
    """The heading anchors as mkdocs (toc) makes them."""
    out = set()
    for h in re.findall(r"^#+ (.*)$", page.read_text(), re.M):
        slug = re.sub(r"[^\w\s-]", "", h.lower()).strip()
        out.add(re.sub(r"[-\s]+", "-", slug))
    return out
