"""mkdocs hook: the result files written by experiments/ and benchmarks/ become pages of the documentation site.

The pages under docs/ link to them by their paths in the repository (``../../experiments/results/orbit_fit.md``), so
the links work when reading the files on disk or on a forge; here those files are added to the site at the same
relative place (``experiments/results/orbit_fit.md`` beside ``docs/``'s pages) and the links are rewritten to it.
"""

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parent
RESULTS = ("experiments/results", "benchmarks")
"""Folders of the repository whose ``.md`` and ``.png`` files join the site."""

_LINK = re.compile(r"\]\(([^)\s#]+)([^)]*)\)")


def _result_files() -> list[str]:
    found = []
    for folder in RESULTS:
        for path in sorted((ROOT / folder).iterdir()):
            if path.suffix in (".md", ".png") and path.is_file():
                found.append(path.relative_to(ROOT).as_posix())
    return found


def on_files(files: Files, config) -> Files:
    for path in _result_files():
        files.append(File(path, str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    """A link from a page under docs/ that leaves docs/ for a result file points to that file's page instead."""
    if page.file.abs_src_path is None or not Path(page.file.abs_src_path).is_relative_to(ROOT / config["docs_dir"]):
        return markdown
    here = posixpath.dirname(page.file.src_uri)

    def rewrite(match: re.Match) -> str:
        target, rest = match.group(1), match.group(2)
        if "://" in target or target.startswith("/"):
            return match.group(0)
        in_repository = posixpath.normpath(posixpath.join("docs", here, target))
        if in_repository.startswith(RESULTS):
            return f"]({posixpath.relpath(in_repository, here or '.')}{rest})"
        return match.group(0)

    return _LINK.sub(rewrite, markdown)


# ---------------------------------------------------------------------------------------------------------------------
# griffe extension (mkdocs.yml: handlers.python.options.extensions): the package documents paired arguments in one
# entry (``latitude, longitude: radians``), which the Google-style parser would report as one unknown parameter.
# Each such entry is repeated once per name, so every name is checked against the signature and documented.

_SECTIONS = ("Args:", "Arguments:", "Parameters:")
_PAIRED = re.compile(r"^(?P<indent>\s*)(?P<names>[A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)+)(?P<rest>\s*(?:\([^)]*\))?:.*)$")


def split_paired_arguments(text: str) -> str:
    """``a, b: text`` entries of an Args section as one entry per name."""
    lines = text.splitlines()
    out: list[str] = []
    section_indent = None
    i = 0
    while i < len(lines):
        line = lines[i]
        indent = len(line) - len(line.lstrip())
        if line.strip() in _SECTIONS:
            section_indent = indent
            out.append(line)
            i += 1
            continue
        if section_indent is not None and line.strip() and indent <= section_indent:
            section_indent = None
        match = _PAIRED.match(line) if section_indent is not None else None
        if match and indent > section_indent:
            block = [match.group("rest")]
            i += 1
            while i < len(lines) and (not lines[i].strip() or len(lines[i]) - len(lines[i].lstrip()) > indent):
                if not lines[i].strip() and (i + 1 >= len(lines) or len(lines[i + 1]) - len(lines[i + 1].lstrip())
                                             <= indent):
                    break
                block.append(lines[i])
                i += 1
            for name in re.split(r"\s*,\s*", match.group("names")):
                out.append(match.group("indent") + name + block[0])
                out.extend(block[1:])
            continue
        out.append(line)
        i += 1
    return "\n".join(out)


try:
    import griffe
except ImportError:  # only the documentation build needs it
    griffe = None

if griffe is not None:

    class PairedArguments(griffe.Extension):
        """Applies :func:`split_paired_arguments` to every function's docstring before it is parsed."""

        def on_function_instance(self, *, node, func, agent, **kwargs) -> None:
            if func.docstring is not None:
                func.docstring.value = split_paired_arguments(func.docstring.value)
