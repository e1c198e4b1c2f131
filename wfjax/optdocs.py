"""``docs/case_files.md``, generated from the option descriptions of :mod:`wfjax.options`.

The prose lives in ``docs/case_files.template.md``; its markers ``<!-- keys -->`` and
``<!-- flags -->`` are replaced by the table of every case key
(:func:`markdown_table`) and the table of every command-line flag
(:func:`flags_table`). Regenerate with ``python -m wfjax.optdocs`` from the project root; a
test checks that the committed page equals the generated text.
"""

from __future__ import annotations

import sys
from pathlib import Path

from .case import _toml_value, default_layer
from .options import COMMANDS, KEYS, OPTIONS

TEMPLATE = Path("docs/case_files.template.md")
PAGE = Path("docs/case_files.md")


# -- documentation --------------------------------------------------------------------------
def markdown_table() -> str:
    """Every key as a Markdown table: key, unit, allowed values, sweep default, subcommands."""
    defaults = {c: default_layer(c) for c in COMMANDS}
    lines = ["| key | unit | allowed | default | read by | meaning |",
             "| --- | --- | --- | --- | --- | --- |"]
    for path, key in KEYS.items():
        shown = {_toml_value(defaults[c][path]) for c in key.commands if path in defaults[c]}
        first = next((defaults[c][path] for c in ("sweep", *key.commands) if path in defaults[c]),
                     None)
        default = "-" if first is None else f"`{_toml_value(first)}`"
        if len(shown) > 1:
            default += " (differs by subcommand)"
        lines.append(f"| `{path}` | {key.unit or '-'} | {key.allowed().replace('|', '/')} | "
                     f"{default} | {', '.join(key.commands)} | {key.doc.replace('|', '/')} |")
    return "\n".join(lines) + "\n"


def flags_table() -> str:
    """Every flag as a Markdown table: flag and aliases, subcommands, case key, allowed
    values in the flag's unit, meaning."""
    lines = ["| flag | subcommands | case key | allowed | meaning |",
             "| --- | --- | --- | --- | --- |"]
    for option in OPTIONS:
        commands = [c for c in (*COMMANDS, "config") if option.offers_flag(c)]
        if not commands:
            continue
        spelled = ", ".join(f"`{f}`" for f in (option.flag, *option.aliases))
        key = f"`{option.path}`" if option.case else "-"
        if option.kind == "bool":
            allowed = "(a switch)"
        else:
            allowed = option.allowed(option.factor, option.flag_unit or option.unit)
        lines.append(f"| {spelled} | {', '.join(commands)} | {key} | "
                     f"{allowed.replace('|', '/')} | {option.doc.replace('|', '/')} |")
    return "\n".join(lines) + "\n"


def render(template: str) -> str:
    """The page: ``template`` with its markers replaced by the generated tables."""
    return template.replace("<!-- keys -->\n", markdown_table()).replace(
        "<!-- flags -->\n", flags_table())


if __name__ == "__main__":
    PAGE.write_text(render(TEMPLATE.read_text()))
    sys.stdout.write(f"wrote {PAGE}\n")
