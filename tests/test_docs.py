"""The docs hold: every example command in them runs, and every relative link points to a file.

Convention: a fenced block whose info string is `console` lists commands, one per line starting
with `$ dockhil ...` (plain commands: no pipes, redirections or `&&`); they run in order from a
scratch folder that has `launch/` and the page's `yaml file=NAME` blocks, and must exit 0.
Blocks marked `sh` are shown, not run (hardware, a running graph, minutes of work).
"""

import os
import re
import shlex
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tests.support.inprocess import run_main

PAGES = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
# Pages being written elsewhere, linked from the index already: remove each once it exists.
PENDING: set[str] = set()  # pages linked before they land (none now)

_FENCE = re.compile(r"^```(\S*)([^\n]*)\n(.*?)^```\s*$", re.M | re.S)
_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
_SHELL = set("|&;<>`$()")


def blocks(text: str):
    """(language, {attribute: value}, body) of each fenced block."""
    for m in _FENCE.finditer(text):
        attrs = dict(a.split("=", 1) for a in m.group(2).split() if "=" in a)
        yield m.group(1), attrs, m.group(3)


def commands(text: str) -> list[str]:
    return [
        line[2:].strip()
        for lang, _, body in blocks(text)
        if lang == "console"
        for line in body.splitlines()
        if line.startswith("$ ")
    ]


def slug(heading: str) -> str:
    """The anchor a Markdown renderer (GitHub's rules) gives a heading."""
    text = heading.strip().lower().replace("`", "")
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = _FENCE.sub("", path.read_text())
    return {slug(m.group(1)) for m in re.finditer(r"^#+\s+(.*)$", text, re.M)}


def broken_links(page: Path, pending=frozenset()) -> list[str]:
    """Relative links of a page whose file (or heading) does not exist, as `target` strings."""
    bad = []
    text = _FENCE.sub("", page.read_text())
    for target in _LINK.findall(text):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        path = (page.parent / file).resolve() if file else page
        rel = os.path.relpath(path, ROOT)
        if not path.exists():
            if rel not in pending:
                bad.append(target)
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            bad.append(target)
    return bad


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_to_files(page):
    assert broken_links(page, PENDING) == []


def test_the_link_check_finds_a_missing_file_and_a_missing_heading(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "# Top\n\n## Two words\n\n[ok](#two-words) [web](https://example.com) [self](page.md#top)\n"
        "[gone](nowhere.md) [bad anchor](page.md#three-words)\n```sh\n[in code](ignored.md)\n```\n"
    )
    assert broken_links(page) == ["nowhere.md", "page.md#three-words"]


def test_the_docs_have_runnable_examples():
    # The pages that explain commands must carry examples that run, so this check cannot pass empty.
    by_page = {p.name: commands(p.read_text()) for p in PAGES if p.parent == ROOT / "docs"}
    for name in ("summary.md", "launch-files.md", "commands.md", "time.md", "hardware.md"):
        assert by_page.get(name), f"docs/{name} has no `console` example"


@pytest.mark.parametrize("page", [p for p in PAGES if commands(p.read_text())], ids=lambda p: str(p.relative_to(ROOT)))
def test_every_console_example_runs(page, tmp_path, monkeypatch):
    (tmp_path / "launch").symlink_to(ROOT / "launch")
    for _lang, attrs, body in blocks(page.read_text()):
        if "file" in attrs:
            (tmp_path / attrs["file"]).write_text(body)
    # Each command runs through the `dockhil` entry point's main() in this process, from the scratch
    # folder: a process per command would cost a Python start-up and the imports again, 0.3-0.5 CPU-s
    # each. A multi-process example still starts its node processes; the entry point as a process
    # of its own is held by test_missing_file (test_launch_refusals.py) and the wheel's test.
    monkeypatch.chdir(tmp_path)
    for line in commands(page.read_text()):
        argv = shlex.split(line)
        assert argv[0] == "dockhil" and not _SHELL & set(line), f"{page.name}: not a plain dockhil command: {line}"
        code, _, err = run_main(*argv[1:])
        assert code == 0 and "Traceback" not in err, f"{page.name}: $ {line}\n{err[-2000:]}"


def test_the_readme_first_screen_says_what_dockhil_is_shows_it_and_gives_the_two_commands():
    """One paragraph, a picture, the two commands (install and run; the checks and tests, exactly
    as .ci/run runs them in its fresh venv), and where to go next; the rest lives in docs/."""
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 40, "the README is one screen: move the rest into docs/"
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.startswith("python3 -m pip")]
    commands = [line.strip() for line in lines if line.startswith("    ")]
    assert (
        commands == ["python3 -m pip install -e . && dockhil launch launch/hil.yaml --summary hil-summary.json", *ci]
        and len(ci) == 1
    )
    picture = re.search(r"!\[[^\]]+\]\((docs/img/[^)\s]+\.png)\)", "\n".join(lines))
    assert picture, "the README shows a picture from docs/img/"
    png = (ROOT / picture.group(1)).read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) < 100_000
    assert "[docs/](docs/README.md)" in "\n".join(lines)
