"""``wfjax config``: print a complete, commented case file, or check one.

``wfjax config --print-defaults > case.toml`` writes every parameter of ``wfjax sweep`` (the
main job) at its default; ``--command simulate`` (or fit, compare, ...) the defaults of another
subcommand. ``wfjax config --config case.toml [--command C]`` checks a case file and prints
it resolved (every key, defaults filled in), or fails with the one-line reason.
``--print-table`` prints the Markdown table of every key (``docs/case_files.md``).
"""

from __future__ import annotations

import sys

from .. import case as case_mod
from ..optdocs import markdown_table

HELP = "print the default case file (--print-defaults) or check and resolve one (--config)"

HEADER = """wfjax case file: every parameter of `wfjax {command}`{what}.
Units: SI unless the key names its unit (speeds_kmh, depth_mm, preload_kN also accepted).
Precedence: command-line flags > this file > WFJAX_PRECISION > defaults.
Every key, unit and range: docs/case_files.md.  Run: wfjax {command} --config case.toml"""


def run(args) -> int:
    from ._common import flag_layer

    flag_layer(args, "config")  # its own flags (--command) checked before anything else
    if args.print_table:
        sys.stdout.write(markdown_table())
        return 0
    if args.print_defaults and (args.config or args.set_values):
        raise ValueError("--print-defaults prints the defaults; leave out --config and --set "
                         "(or drop --print-defaults to print the resolved case)")
    if args.print_defaults:
        case = case_mod.default_case(args.case_command)
        what = ", at its default" if args.case_command != "sweep" else \
            ", at its default (the main job: Fig. 7's flats, 3D contact)"
    elif args.config or args.set_values:
        from ._common import resolve_case

        case = resolve_case(args, args.case_command)
        what = f", resolved from {args.config or '--set'}"
    else:
        raise ValueError("give --print-defaults, --print-table or --config FILE")
    header = HEADER.format(command=args.case_command, what=what)
    sys.stdout.write(case.to_toml(header, comments=not args.no_comments))
    return 0
