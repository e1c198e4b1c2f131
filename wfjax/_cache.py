"""A small, generic on-disk cache of named dictionaries of numpy arrays.

``load_or_build(name, key, build)`` returns the arrays stored under a hash of ``key`` and the
wfjax version, or calls ``build()``, stores and returns its result.

Files are ``<cache dir>/<name>-<hash>.npz.sha256``: a 64-character hex SHA-256 of the payload,
a space, the entry's own key hash (64 hex, of which ``<hash>`` is the first 24), a newline,
then the ``.npz`` payload. They are written to a uniquely named temporary file in the same
directory (:func:`wfjax.outputs.unique_temporary`) and moved into place with ``os.replace``
(atomic), and verified on load: a file whose checksum or contents do not match, or whose
recorded key is not the one its name stands for (a renamed or copied entry), is rebuilt,
never trusted. (An entry written before keys were recorded is read once under the name its
key gives, and rewritten with the key.) Temporary files left by killed writers are removed
by the next write.
A cache directory that cannot be written makes every run rebuild its tables: a one-line
warning on stderr says so, once per process.

Cache directory: the ``cache_dir`` argument, else the environment variable
``WFJAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/wfjax`` (``~/.cache/wfjax``).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .outputs import clean_stale, unique_temporary

__all__ = ["cache_directory", "cache_path", "load_or_build", "key_hash"]


def cache_directory(cache_dir: str | os.PathLike | None = None) -> Path:
    """The cache directory: argument, else ``$WFJAX_CACHE_DIR``, else ``~/.cache/wfjax``."""
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("WFJAX_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "wfjax"


def _canonical(value):
    if isinstance(value, dict):
        return {str(k): _canonical(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if hasattr(value, "shape") and hasattr(value, "dtype"):
        arr = np.asarray(value)
        return {"dtype": str(arr.dtype), "shape": list(arr.shape),
                "sha256": hashlib.sha256(np.ascontiguousarray(arr).tobytes()).hexdigest()}
    if isinstance(value, float):
        return repr(float(value))
    if isinstance(value, (int, str, bool)) or value is None:
        return value
    return repr(value)


def key_hash(name: str, key: dict) -> str:
    """SHA-256 hex digest of ``name``, ``key`` (canonical JSON) and the wfjax version."""
    import wfjax

    payload = json.dumps({"name": name, "key": _canonical(key),
                          "version": getattr(wfjax, "__version__", "unknown")}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()


_FULL_KEYS: dict[str, str] = {}  # entry file name -> its full key hash
_WARNED: set[str] = set()


def cache_path(name: str, key: dict, cache_dir=None) -> Path:
    """The file that holds (or will hold) the entry ``name``/``key``."""
    full = key_hash(name, key)
    path = cache_directory(cache_dir) / f"{name}-{full[:24]}.npz.sha256"
    _FULL_KEYS[path.name] = full
    return path


def _read(path: Path) -> dict[str, np.ndarray] | None:
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    header, sep, payload = blob.partition(b"\n")
    digest, _, recorded = header.partition(b" ")
    if not sep or hashlib.sha256(payload).hexdigest().encode() != digest:
        return None
    stem = path.name.removesuffix(".npz.sha256")
    expected = _FULL_KEYS.get(path.name)
    legacy = not recorded and expected is not None  # written before keys were recorded
    if not legacy and (len(recorded) != 64 or not stem.endswith(
            "-" + recorded[:24].decode("ascii", "replace"))):
        return None  # the entry of another key, renamed or copied here
    if not legacy and expected is not None and expected.encode() != recorded:
        return None
    try:
        with np.load(io.BytesIO(payload), allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception:  # noqa: BLE001 - any unreadable payload means "rebuild"
        return None
    if legacy:  # rewritten once with its key recorded
        store(path, arrays)
    return arrays


def _write(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    payload = buf.getvalue()
    full = _FULL_KEYS.get(path.name)
    if full is None:
        raise OSError(f"{path}: not a cache entry's name (made by cache_path)")
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_stale(path.parent)
    _clean_legacy(path.parent)
    tmp = unique_temporary(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(hashlib.sha256(payload).hexdigest().encode() + b" " + full.encode()
                     + b"\n" + payload)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _clean_legacy(directory: Path, age: float = 3600.0) -> None:
    """Remove the temporary files of older wfjax versions (``.<entry>.npz.sha256.<random>``,
    no process id in the name) once they are ``age`` [s] old: their writer is long gone."""
    now = time.time()
    for tmp in directory.glob(".*.npz.sha256.*"):
        with contextlib.suppress(OSError):
            if now - tmp.stat().st_mtime > age:
                tmp.unlink()


def store(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` to the cache file ``path`` (:func:`cache_path`) atomically; a cache
    directory that cannot be written is skipped (the caller keeps its arrays) with a one-line
    warning on stderr, once per directory and process."""
    try:
        _write(path, {k: np.asarray(v) for k, v in arrays.items()})
    except OSError as exc:
        where = str(path.parent)
        if where not in _WARNED:
            _WARNED.add(where)
            print(f"wfjax: warning: cannot write the cache {where}: {exc.strerror or exc}; "
                  "every run rebuilds its tables (much slower): set WFJAX_CACHE_DIR to a "
                  "writable directory", file=sys.stderr)


def load_or_build(name: str, key: dict, build: Callable[[], dict[str, np.ndarray]],
                  cache_dir: str | os.PathLike | None = None) -> dict[str, np.ndarray]:
    """Load the arrays cached under ``name``/``key``, or build, store and return them.

    Args:
        name: short file-name-safe label of the kind of entry (e.g. ``"track-modal"``).
        key: every input the result depends on (numbers, strings, arrays, nested dicts).
        build: zero-argument function returning a dict of numpy arrays.
        cache_dir: cache directory (see :func:`cache_directory`).

    Returns:
        dict of numpy arrays (identical to what ``build()`` returned when it was stored).
        If the cache directory cannot be written, the freshly built result is returned.
    """
    path = cache_path(name, key, cache_dir)
    cached = _read(path)
    if cached is not None:
        return cached
    arrays = {k: np.asarray(v) for k, v in build().items()}
    store(path, arrays)
    return arrays
