"""Bounds on what ``wfjax`` reads and writes: file size, list length, nesting, output size.

Every input file (case TOML, JSON summary used as ``--config``, profile CSV, roughness CSV,
fit data CSV) is read through :func:`read_text`: at most ``limit + 1`` bytes are read, so a
file that never ends (``/dev/zero``, a FIFO fed forever) is refused at once, without
filling the memory. A FIFO without a writer reads as empty instead of blocking.

The defaults (``docs/case_files.md``, "Limits"):

* :data:`MAX_INPUT_BYTES`: 64 MB per input file (environment ``WFJAX_MAX_INPUT_BYTES``);
* :data:`MAX_LIST`: 10^5 entries per list (speeds, depths, sensors, void sleepers, ...);
* :data:`MAX_DEPTH`: nesting depth 32 of a case file's tables and lists;
* :data:`MAX_OUTPUT_BYTES`: 1 GB of predicted output per run, unless ``--allow-large-output``
  (or ``[run] allow_large_output = true``).

Every breach raises :class:`InputError` (a ``ValueError``: one line, exit status 2).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping

__all__ = ["InputError", "MAX_INPUT_BYTES", "MAX_LIST", "MAX_DEPTH", "MAX_OUTPUT_BYTES",
           "input_limit", "read_bytes", "read_text", "parse_document", "check_tree", "check_list",
           "check_output_size"]

MAX_INPUT_BYTES = 64_000_000  # bytes per input file (64 MB)
MAX_LIST = 100_000  # entries per list
MAX_DEPTH = 32  # nesting of tables and lists in a case file
MAX_OUTPUT_BYTES = 1_000_000_000  # bytes of predicted output per run (1 GB)
_CHUNK = 1 << 20


class InputError(ValueError):
    """An input beyond a limit, or unreadable: one line naming what the user gave."""


def input_limit() -> int:
    """The size limit of one input file [bytes]: ``$WFJAX_MAX_INPUT_BYTES`` or 64 MB."""
    text = os.environ.get("WFJAX_MAX_INPUT_BYTES", "")
    try:
        value = int(text) if text else MAX_INPUT_BYTES
    except ValueError:
        raise InputError(f"WFJAX_MAX_INPUT_BYTES={text!r}: not an integer number of bytes") \
            from None
    if value <= 0:
        raise InputError(f"WFJAX_MAX_INPUT_BYTES={text}: must be > 0 bytes")
    return value


def _open(path: str) -> int:
    """A read-only descriptor of ``path``; a FIFO opens without waiting for a writer."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(21, "is a directory", path)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_bytes(path: str | os.PathLike, what: str, limit: int | None = None) -> bytes:
    """The bytes of the input file ``path``, at most ``limit`` (default :func:`input_limit`).

    Args:
        path: the file (a regular file, a FIFO or a device).
        what: how the user named it, for messages (``"--profile-csv data.csv"``).
        limit: the size limit [bytes].

    Raises:
        InputError: the file cannot be read, or holds more than ``limit`` bytes (found after
            reading at most ``limit + 1`` bytes).
    """
    limit = input_limit() if limit is None else int(limit)
    try:
        fd = _open(os.fspath(path))
    except OSError as exc:
        raise InputError(f"{what}: cannot read: {exc.strerror or exc}") from None
    chunks, size = [], 0
    try:
        while size <= limit:
            block = os.read(fd, min(_CHUNK, limit + 1 - size))
            if not block:
                break
            chunks.append(block)
            size += len(block)
    except OSError as exc:
        raise InputError(f"{what}: cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if size > limit:
        raise InputError(f"{what}: larger than {limit:,} bytes, the limit of an input file "
                         "(WFJAX_MAX_INPUT_BYTES; docs/case_files.md, Limits)")
    return b"".join(chunks)


def read_text(path: str | os.PathLike, what: str, limit: int | None = None) -> str:
    """The UTF-8 text of the input file ``path`` (a leading byte-order mark dropped, as Excel
    writes it), read by :func:`read_bytes`; ``what`` names it in messages.

    Raises:
        InputError: too large, unreadable, or not UTF-8 (naming the byte offset).
    """
    data = read_bytes(path, what, limit)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise InputError(f"{what}: not UTF-8 text (byte {exc.start}, line {line}: "
                         f"{data[exc.start:exc.start + 1]!r}); save it as UTF-8") from None


def check_list(value, what: str, limit: int = MAX_LIST) -> None:
    """Refuse a list (or tuple) of more than ``limit`` entries, naming ``what``."""
    if isinstance(value, (list, tuple)) and len(value) > limit:
        raise InputError(f"{what}: {len(value):,} entries; allowed: at most {limit:,} per list "
                         "(docs/case_files.md, Limits)")


def check_tree(data, source: str, depth: int = MAX_DEPTH) -> None:
    """Refuse nesting deeper than ``depth`` or a list longer than :data:`MAX_LIST` anywhere
    in parsed case data ``data`` (dicts and lists), naming the ``source`` and the key path."""
    stack = [(data, "", 1)]
    while stack:
        node, where, level = stack.pop()
        if level > depth:
            raise InputError(f"{source}: {where or 'the document'}: nested deeper than "
                             f"{depth} levels (docs/case_files.md, Limits)")
        if isinstance(node, Mapping):
            stack.extend((v, f"{where}.{k}" if where else str(k), level + 1)
                         for k, v in node.items())
        elif isinstance(node, list):
            check_list(node, f"{source}: {where or 'the document'}")
            stack.extend((v, f"{where}[{i}]", level + 1) for i, v in enumerate(node)
                         if isinstance(v, (Mapping, list, str)))
        elif isinstance(node, str) and node.count(",") >= MAX_LIST:  # "a,b,c" list text
            check_list(node.split(","), f"{source}: {where}")


def parse_document(text: str, source: str, is_json: bool):
    """The parsed JSON or TOML ``text`` of the case file ``source``, checked by
    :func:`check_tree`; bad syntax or nesting raises :class:`InputError` (one line)."""
    import json
    import tomllib

    try:
        data = json.loads(text) if is_json else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"{source}: not valid {'JSON' if is_json else 'TOML'}: {exc}") \
            from None
    except RecursionError:
        raise InputError(f"{source}: nested deeper than {MAX_DEPTH} levels "
                         "(docs/case_files.md, Limits)") from None
    check_tree(data, source)
    return data


def check_output_size(predicted: float, what: str, allowed: bool = False,
                      limit: int = MAX_OUTPUT_BYTES) -> None:
    """Refuse a run whose outputs are predicted at more than ``limit`` bytes.

    Args:
        predicted: the predicted size of the run's output files [bytes].
        what: what makes them large, in the user's words (``"12 speeds x 1000 positions"``).
        allowed: ``--allow-large-output`` was given: no refusal.
    """
    if predicted > limit and not allowed:
        raise InputError(f"{what}: the outputs would take about {predicted / 1e9:.3g} GB, more "
                         f"than the {limit / 1e9:g} GB limit; give fewer entries, or "
                         "--allow-large-output (run.allow_large_output = true)")

