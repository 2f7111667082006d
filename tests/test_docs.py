"""The README and the documentation site (``docs/``, built by ``make docs``) say what the code does: the module table
lists exactly the modules in the tree, every Python snippet runs, the README's printout is what its command prints,
the README's command table lists every verb of ``seaice``, the API reference covers the public names, the site's
navigation lists every page, and relative links point to files that exist."""

import argparse
import importlib
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from seaice_jax.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "seaice_jax"
README = ROOT / "README.md"
DOCS = ROOT / "docs"
ARCHITECTURE = DOCS / "design" / "architecture.md"
README_LINES = 200
"""The README stays an entrance: what the package is, how to start, where to read on."""


def _pages() -> list[Path]:
    return [README, *sorted(DOCS.rglob("*.md"))]


def _section(text: str, heading: str) -> str:
    """The body of the ``## heading`` section of a Markdown text."""
    assert f"\n## {heading}\n" in text, f"no section '## {heading}'"
    return text.split(f"\n## {heading}\n", 1)[1].split("\n## ", 1)[0]


# --- the module table ------------------------------------------------------------------------------------------------

def _module_table() -> list[str]:
    """The backquoted module paths in the first column of the module table (docs/design/architecture.md)."""
    listed = []
    for row in _section(ARCHITECTURE.read_text(), "Modules").splitlines():
        if row.startswith("| `"):
            listed += re.findall(r"`([\w/]+\.py)`", row.split("|")[1])
    return listed


def test_module_table_matches_the_tree():
    """Every public module (not ``__init__``, not ``_private``) is listed exactly once, and nothing else."""
    tree = sorted(str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if not p.name.startswith("_"))
    listed = _module_table()
    assert sorted(set(listed)) == sorted(listed), "listed twice: " + ", ".join(
        sorted({m for m in listed if listed.count(m) > 1}))
    assert not set(tree) - set(listed), f"not in the module table of {ARCHITECTURE.relative_to(ROOT)}: " + ", ".join(
        sorted(set(tree) - set(listed)))
    assert not set(listed) - set(tree), f"in the module table of {ARCHITECTURE.relative_to(ROOT)} but not in the " \
        "tree: " + ", ".join(sorted(set(listed) - set(tree)))


# --- Python snippets -------------------------------------------------------------------------------------------------

def _snippets() -> list[tuple[str, str]]:
    """``(id, source)`` of every ```python block of the README and the docs pages."""
    found = []
    for page in _pages():
        for number, source in enumerate(re.findall(r"^```python\n(.*?)^```", page.read_text(), re.S | re.M), 1):
            found.append((f"{page.relative_to(ROOT)}#{number}", source))
    return found


def test_docs_have_snippets():
    assert len(_snippets()) >= 5


SLOW_SNIPPETS = {"docs/workflows/radar-blocks.md#1", "docs/workflows/satellite-sequences.md#1",
                 "docs/workflows/sentinel1.md#1"}
"""Whole workflows (a radar block, a sequence adjusted and remapped, a Sentinel-1 product's grid reproduced and its
image remapped: 5-19 s each): run by `make test-slow`."""


@pytest.mark.parametrize("source", [pytest.param(s, id=i, marks=[pytest.mark.slow] if i in SLOW_SNIPPETS else [])
                                    for i, s in _snippets()])
def test_snippet_runs(source, tmp_path):
    """Each ```python block runs on its own in a fresh interpreter (CPU), in an empty folder holding a copy of
    ``examples/`` (the files the commands use)."""
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    environment = {**os.environ, "JAX_PLATFORMS": "cpu", "MPLBACKEND": "Agg"}
    result = subprocess.run([sys.executable, "-c", source], cwd=tmp_path, capture_output=True, text=True,
                            timeout=600, env=environment)
    assert result.returncode == 0, f"snippet failed:\n{source}\n{result.stderr[-3000:]}"


# --- the README's printout -------------------------------------------------------------------------------------------

PRINTOUT = re.compile(r"<!-- printout: (?P<command>.*?) -->\n~~~text\n(?P<block>.*?)~~~\n", re.S)
"""A printout of the README: the command that prints it, in a comment, then its first lines in a text block (fenced
by ``~~~``, so that tests/test_cli_habits.py, which runs the README's ```sh commands, does not read it as one)."""
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


def _same_line(expected: str, actual: str) -> bool:
    """The same text, and the same numbers to ±1 in the last digit the README prints (the last digit of a rounded
    float may differ between machines and XLA's code generation; integers, counts and flags must agree)."""
    if _NUMBER.sub("#", expected).split() != _NUMBER.sub("#", actual).split():
        return False
    for want, got in zip(_NUMBER.findall(expected), _NUMBER.findall(actual), strict=True):
        if "." not in want:
            if want != got:
                return False
        elif abs(float(want) - float(got)) > 1.001 * 10.0 ** -len(want.split(".")[1]):
            return False
    return True


def test_same_line_is_strict_where_it_should_be():
    assert _same_line("SIGMA0 1.114 WITH 5 DEGREES", "SIGMA0 1.115 WITH 5 DEGREES")
    assert not _same_line("SIGMA0 1.114 WITH 5 DEGREES", "SIGMA0 1.116 WITH 5 DEGREES")
    assert not _same_line("SIGMA0 1.114 WITH 5 DEGREES", "SIGMA0 1.114 WITH 6 DEGREES")
    assert not _same_line("GLOBAL TEST ACCEPTED", "GLOBAL TEST REJECTED")
    assert not _same_line("3030  COB IS ICE   164", "3030  COB IS ICE   164  *")


def test_readme_printout_is_what_its_command_prints(tmp_path, monkeypatch, capsys):
    """The README's printout block equals the first lines its command prints today. With ``SEAICE_UPDATE_README=1``
    the block is rewritten from this run instead."""
    text = README.read_text()
    match = PRINTOUT.search(text)
    assert match, "the README has no printout block"
    monkeypatch.chdir(tmp_path)
    assert main(["examples", "-q"]) == 0
    capsys.readouterr()
    words = shlex.split(match["command"])
    assert words[0] == "seaice"
    assert main(words[1:]) == 0
    printed = [line.rstrip() for line in capsys.readouterr().out.splitlines()]
    expected = match["block"].splitlines()
    if os.environ.get("SEAICE_UPDATE_README"):
        block = "\n".join(printed[:len(expected)]) + "\n"
        README.write_text(text[:match.start("block")] + block + text[match.end("block"):])
        return
    assert len(printed) >= len(expected), f"the command printed {len(printed)} lines, the README shows {len(expected)}"
    wrong = [f"README:  {want}\nprinted: {got}" for want, got in zip(expected, printed, strict=False)
             if not _same_line(want, got)]
    assert not wrong, "the README's printout differs from the command's (SEAICE_UPDATE_README=1 rewrites it):\n" + \
        "\n".join(wrong)


# --- the command table -----------------------------------------------------------------------------------------------

def _verbs(parser, prefix="") -> set[str]:
    """Every command of the parser, a group's verbs as ``"group verb"`` (``sar geolocate``)."""
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    found = set()
    for name, command in action.choices.items():
        if any(isinstance(a, argparse._SubParsersAction) for a in command._actions):
            found |= _verbs(command, f"{prefix}{name} ")
        else:
            found.add(f"{prefix}{name}")
    return found


def test_readme_command_table_lists_every_verb():
    rows = re.findall(r"^\| `seaice ([a-z][a-z ]*)` \|", _section(README.read_text(), "Commands"), re.M)
    assert len(rows) == len(set(rows)), "a command listed twice"
    verbs = _verbs(build_parser())
    assert not verbs - set(rows), "not in the README's command table: " + ", ".join(sorted(verbs - set(rows)))
    assert not set(rows) - verbs, "in the README's command table but not a command: " + ", ".join(
        sorted(set(rows) - verbs))


def test_readme_is_short():
    assert len(README.read_text().splitlines()) <= README_LINES


# --- the site --------------------------------------------------------------------------------------------------------

def test_api_reference_covers_the_public_names():
    """Every ``::: name`` of docs/reference/ is a public name of the package or an importable module, and every name
    of ``seaice_jax.__all__`` has its entry."""
    import seaice_jax

    named = [name for page in sorted((DOCS / "reference").glob("*.md"))
             for name in re.findall(r"^::: ([\w.]+)", page.read_text(), re.M)]
    public = set(seaice_jax.__all__)
    for name in named:
        head, _, tail = name.rpartition(".")
        if head == "seaice_jax" and tail in public:
            continue
        importlib.import_module(name)  # a module documented whole
    missing = public - {name.rpartition(".")[2] for name in named if name.rpartition(".")[0] == "seaice_jax"}
    assert not missing, "public names without an API reference entry: " + ", ".join(sorted(missing))


def test_every_page_is_in_the_navigation():
    navigation = set(re.findall(r":\s*([\w/.-]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M))
    pages = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md")}
    assert pages == navigation, f"pages not in mkdocs.yml's nav: {sorted(pages - navigation)}; " \
        f"nav entries without a page: {sorted(navigation - pages)}"


_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)[^)]*\)")


def test_relative_links_point_to_files():
    broken = []
    for page in _pages():
        text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M)  # not inside code blocks
        for target in _LINK.findall(text):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            if not (page.parent / target.split("#")[0]).exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
    assert not broken, "links to files that do not exist:\n" + "\n".join(broken)
