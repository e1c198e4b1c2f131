"""The ``wfjax`` command: one entry point, one module per subcommand in ``wfjax.commands``.

Each subcommand module defines ``HELP`` (one line) and ``run(args) -> int``; its flags come
from the option descriptions of :mod:`wfjax.options` (:func:`add_options`). Bad input (flags,
case files, data files) exits with status 2 and a one-line reason on stderr, before any
computation; a file that cannot be written exits 1, SIGTERM 143 and Ctrl-C 130, each with
one line and nothing of the run's outputs left (:mod:`wfjax.outputs`).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import signal
import sys

SUBCOMMANDS = ("sweep", "simulate", "compare", "figures", "fit", "receptance", "geometry",
               "detector", "identify", "config", "examples")
VERSION_FLAGS = ("--version", "-V")


def _available():
    for name in SUBCOMMANDS:
        try:
            yield name, importlib.import_module(f"wfjax.commands.{name}")
        except ModuleNotFoundError as exc:  # a subcommand not built yet
            if exc.name != f"wfjax.commands.{name}":
                raise


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (and exit status 2), like the others."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _Typed(argparse.Action):
    """Store a flag's text and the spelling typed (``--depths-mm``), which errors name."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        namespace._typed = {**getattr(namespace, "_typed", {}), self.dest: option_string}


def _in_flag_unit(value, option) -> str:
    """An SI ``value`` as the flag writes it (``0.0009`` m -> ``0.9`` for ``--depth-mm``)."""
    if isinstance(value, list):
        return ",".join(_in_flag_unit(v, option) for v in value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value / option.factor:g}"
    return str(value)


def flag_help(option, command: str, defaults: dict) -> str:
    """The ``--help`` line of ``option`` in ``wfjax command``: meaning, unit, default."""
    unit = option.flag_unit or option.unit
    text = option.doc + (f" [{unit}]" if unit and option.kind not in ("str", "path") else "")
    if option.choice_list is not None:
        text += f" ({' | '.join(option.choice_list)})"
    default = defaults.get(option.path) if option.case else option.default_for(command)
    if option.kind == "bool" or default in (None, [], ""):
        return text
    return f"{text} (default: {_in_flag_unit(default, option)})"


def add_options(parser: argparse.ArgumentParser, command: str) -> None:
    """Every flag of ``wfjax command``, generated from :mod:`wfjax.options` (the one place
    that calls ``add_argument``). Flags of case keys default to None (the case file, the
    environment or the subcommand's default decide); their text is checked and converted by
    :func:`wfjax.commands._common.flag_layer`."""
    from .case import default_layer
    from .options import flags_of

    defaults = default_layer(command)
    for option in flags_of(command):
        kw = {"dest": option.flag_dest, "default": option.default_for(command),
              "help": flag_help(option, command, defaults).replace("%", "%%")}
        if option.action == "store_true":
            kw["action"] = option.action
        elif option.action:
            kw.update(action=option.action, metavar=option.metavar)
        else:
            # no argparse ``choices``: the generated validation refuses a bad name with the
            # same one-line error (and exit status 2) as every other bad value
            kw.update(action=_Typed, metavar=option.metavar)
        if not option.flag.startswith("-"):  # a positional argument, optional (``[DIR]``)
            del kw["dest"]
            kw["nargs"] = "?"
        parser.add_argument(option.flag, *option.aliases, **kw)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``wfjax`` command with every available subcommand."""
    parser = _Parser(
        prog="wfjax", description="Wheel-flat impact forces (Pieringer, Kropp & Nielsen 2014).",
        epilog="wfjax --version prints the version.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name, module in _available():
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        add_options(p, name)
        p.set_defaults(_run=module.run)
    return parser


def enable_compilation_cache() -> None:
    """Persist XLA compilations in ``<wfjax cache dir>/xla`` so a new process reuses them.

    Set here, in the command-line entry point, not on ``import wfjax`` (library users choose
    their own JAX configuration). Every compilation is kept, however short: with JAX's 1 s
    threshold a warm ``wfjax figures --only 8`` compiled its laws' batch (0.52 s) and five
    small programs again in every process.
    """
    import jax

    from ._cache import cache_directory

    jax.config.update("jax_compilation_cache_dir", str(cache_directory() / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def expose_cpu_cores(count: int | None = None) -> None:
    """On a CPU, ``count`` JAX devices (default: one per core), so ``sweep`` shards over them.

    XLA's CPU backend runs one batched time loop on one core; as separate devices the cores
    each run a share of the runs (``benchmarks/README.md``, "Scale-out"). Only effective before
    JAX initialises its backends; a device count the user put in ``XLA_FLAGS`` wins, and GPU
    or TPU devices, when present, are used instead of these.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        device_count = f"--xla_force_host_platform_device_count={count or os.cpu_count() or 1}"
        os.environ["XLA_FLAGS"] = f"{flags} {device_count}".strip()


def main(argv: list[str] | None = None) -> int:
    """Run the ``wfjax`` command line; returns the exit status.

    ``wfjax --version`` (or ``-V``) prints ``wfjax X.Y.Z`` (:data:`wfjax.__version__`, the
    version the package was built with) and nothing else runs.
    """
    from . import __version__, outputs
    from .commands._common import NonFiniteResult, user_words
    from .scenario import guards

    first = (sys.argv[1:] if argv is None else argv)[:1]
    if first and first[0] in VERSION_FLAGS:
        print(f"wfjax {__version__}")
        return 0
    expose_cpu_cores()
    args = build_parser().parse_args(argv)
    enable_compilation_cache()
    with _terminate_as_exception():
        try:
            with outputs.session(args.command), guards.recorded():
                return int(args._run(args) or 0)
        except ValueError as exc:
            return _fail(args.command, user_words(str(exc)), 2)
        except NonFiniteResult as exc:
            return _fail(args.command, str(exc), 1)
        except outputs.OutputError as exc:
            return _fail(args.command, f"{exc.strerror}; {_NOTHING}", 1)
        except OSError as exc:
            where = f": {exc.filename}" if exc.filename else ""
            return _fail(args.command, f"{exc.strerror or exc}{where}", 1)
        except Terminated:
            return _fail(args.command, f"terminated (SIGTERM); {_left(outputs)}", 143)
        except KeyboardInterrupt:
            return _fail(args.command, f"interrupted (Ctrl-C); {_left(outputs)}", 130)


def _left(outputs) -> str:
    """What an interrupted run left: nothing, or (a signal during the commit, delivered
    after it) its complete outputs."""
    done = outputs.committed()
    return f"its outputs in {done[0]} are complete" if done else _NOTHING


_NOTHING = "nothing of this run was written, --out keeps its previous files"


class Terminated(BaseException):
    """SIGTERM arrived: unwinds like Ctrl-C, so the run's staging files are removed."""


def _fail(command: str, message: str, status: int) -> int:
    """Print ``message`` as the command's one-line error; return ``status``."""
    print(f"wfjax {command}: error: {message}", file=sys.stderr)
    return status


@contextlib.contextmanager
def _terminate_as_exception():
    """Within: SIGTERM raises :class:`Terminated` (exit status 143, like a killed process)
    and SIGINT ``KeyboardInterrupt``, held while a commit renames (:func:`wfjax.outputs.defer`);
    a second signal while the first unwinds (removing the run's staging files) is ignored.
    The previous handlers are restored after. Outside the main thread: no change."""
    from .outputs import defer

    def handler(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        exc = Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
        if not defer(exc):  # held while a commit renames: raised when it ends
            raise exc

    try:
        previous = {s: signal.signal(s, handler) for s in (signal.SIGTERM, signal.SIGINT)}
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


def entry_point() -> None:
    """The ``wfjax`` console script: :func:`main`, then the process ends at once.

    Python's teardown after a finished command (freeing every module of JAX, SciPy and
    matplotlib, and the compiled programs) took 0.7-0.9 s of the main job's wall time on the
    2-core CPU and does nothing the command needs: its files are written and closed, the
    compilation cache is written when a program compiles. So after flushing the output
    streams and the logging handlers the process exits without it (``os._exit``). An
    exception that escapes :func:`main` still ends the process the usual way.
    """
    status = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


if __name__ == "__main__":
    entry_point()
