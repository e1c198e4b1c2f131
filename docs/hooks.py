"""mkdocs hooks of the documentation site (``mkdocs.yml``): pages from outside ``docs/``.

* The notebooks of ``notebooks/`` join the site as pages ``notebooks/NAME/`` (rendered by
  mkdocs-jupyter from their stored outputs, never executed), so they stay where Jupyter users
  and ``tests/test_notebooks.py`` find them.
* ``<!-- include: PATH -->`` in a page is replaced by the file ``PATH`` (relative to the
  project root) and ``<!-- include: PATH#Heading -->`` by its section ``## Heading`` (up to
  the next ``## ``), so the benchmark table and the changelog are written once.
* Units and shapes in square brackets (``force [N]``, ``values [n] [m]``) read as Markdown
  reference links to autorefs, whose "Could not find cross-reference target" would fail the
  strict build: those warnings are dropped for targets that are not dotted Python names
  (``wfjax.foo``); an unresolved reference to a dotted name still fails the build.
* The docstrings' Sphinx roles (``:class:`wfjax.Flat```, ``:func:`~wfjax.sweeps.sweep```),
  which Markdown shows literally, are rendered as the code they mark.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

INCLUDE = re.compile(r"<!-- include: (?P<path>[^#>\s]+)(?:#(?P<section>[^>]+?))? -->")


ROLE = re.compile(r":(?:class|func|meth|attr|data|mod|exc|obj|const):<code>~?")
UNRESOLVED = re.compile(r"Could not find cross-reference target '(?P<target>[^']*)'")
DOTTED = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+")


class _UnitBrackets(logging.Filter):
    """Drops autorefs' unresolved-reference warnings whose target is not a dotted name."""

    def filter(self, record: logging.LogRecord) -> bool:
        match = UNRESOLVED.search(record.getMessage())
        return match is None or DOTTED.fullmatch(match["target"]) is not None


def on_config(config):
    logger = logging.getLogger("mkdocs.plugins.mkdocs_autorefs._internal.plugin")
    if not any(isinstance(f, _UnitBrackets) for f in logger.filters):
        logger.addFilter(_UnitBrackets())
    return config


def _root(config) -> Path:
    return Path(config.config_file_path).resolve().parent


@event_priority(50)  # before mkdocs-jupyter's on_files, which turns .ipynb files into pages
def on_files(files, config):
    root = _root(config)
    for path in sorted((root / "notebooks").glob("*.ipynb")):
        files.append(File(path.relative_to(root).as_posix(), str(root), config.site_dir,
                          config.use_directory_urls))
    return files


def section(text: str, heading: str) -> str:
    """The section ``## heading`` of Markdown ``text`` (without its heading line)."""
    lines = text.splitlines()
    start = lines.index(f"## {heading}") + 1
    end = next((i for i in range(start, len(lines)) if lines[i].startswith("## ")),
               len(lines))
    return "\n".join(lines[start:end]).strip() + "\n"


def on_page_markdown(markdown, page, config, files):
    root = _root(config)

    def include(match):
        text = (root / match["path"]).read_text(encoding="utf-8")
        return section(text, match["section"].strip()) if match["section"] else text

    return INCLUDE.sub(include, markdown)


def on_page_content(html, page, config, files):
    return ROLE.sub("<code>", html)
