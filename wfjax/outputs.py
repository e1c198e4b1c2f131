"""A run's output files, written as a whole set or not at all (``docs/outputs.md``).

The scheme: **staging files, a commit journal, renames, a manifest.**

1. Every file of the run is written to a staging file in ``--out`` with a unique name,
   ``.wfjax-<pid>-<random>-<name>`` (nothing of the old set is touched meanwhile).
2. Commit: the staging files are flushed to disk; then the journal
   ``.wfjax-<command>.commit.json`` (every name, its staging file and sha256, and the old
   set's files the new set drops) is written atomically. Writing the journal is the commit
   point. The old manifest is removed, each staging file renamed over its name, the dropped
   files removed, the manifest ``<command>.manifest.json`` (names and sha256) written, and
   the journal removed.
3. Recovery, at the start of the next run of the same command in that directory: a journal
   left by a killed commit is rolled forward (its renames finished, its manifest written);
   staging files whose process is gone are removed.

So after a crash at any point ``--out`` holds the old complete set, or the new one, or a
journal from which the next run completes the new one; a manifest is only present, and
matches, when its set is whole (:func:`verify`). Files not named by a set are never touched.

In the ``wfjax`` command line (:func:`session`), the set is committed when the command
returns and discarded (every staging file removed) when it raises: an error such as ENOSPC,
SIGTERM or Ctrl-C. Library calls outside a session write each file atomically on its own.

Test hook: with ``WFJAX_TEST_PAUSE_WRITER=<file>`` the writer, once the first file of a set is
staged, creates ``<file>`` and waits up to 60 s, so a test can signal a run mid-write.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import secrets
import time
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = ["OutputSet", "OutputError", "session", "active", "committed", "stage", "verify",
           "clean_stale",
           "unique_temporary", "TEMP_PREFIX"]

TEMP_PREFIX = ".wfjax-"
_TEMP = re.compile(r"^\.wfjax-(\d+)-[0-9a-f]{8}-")
PAUSE_ENV = "WFJAX_TEST_PAUSE_WRITER"
_ACTIVE: dict[str, object] = {"command": None, "set": None}
_CRITICAL: dict[str, object] = {"depth": 0, "pending": None}
_COMMITTED: list[Path] = []  # the directories the current session's sets were committed to


class OutputError(OSError):
    """A file of the run's set could not be written: nothing of the run is left."""


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def unique_temporary(path: Path) -> Path:
    """A new empty file next to ``path`` named ``.wfjax-<pid>-<random>-<name>`` (mode 0666
    less the umask); the name ends in ``path.name``, so its suffix is kept."""
    path = Path(path)
    for _ in range(100):
        tmp = path.with_name(f"{TEMP_PREFIX}{os.getpid()}-{secrets.token_hex(4)}-{path.name}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue
    raise OSError(f"cannot create a temporary file next to {path}")


def clean_stale(directory: Path) -> list[str]:
    """Remove the staging files in ``directory`` whose writing process is gone; returns
    their names (files of live processes, and every other file, are left alone)."""
    removed = []
    try:
        names = os.listdir(directory)
    except OSError:
        return removed
    for name in names:
        match = _TEMP.match(name)
        if match and not _alive(int(match.group(1))):
            with contextlib.suppress(OSError):
                os.unlink(Path(directory) / name)
                removed.append(name)
    return removed


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:
        pass  # a directory or a file system without fsync
    finally:
        os.close(fd)


def _write_small(path: Path, data: dict) -> None:
    """``data`` as JSON at ``path``, atomically (temporary file, fsync, rename)."""
    tmp = unique_temporary(path)
    try:
        with open(tmp, "w") as fh:
            json.dump(data, fh, indent=1)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class OutputSet:
    """The files one ``command`` writes into the directory ``out``, committed as a whole.

    Use :meth:`stage` for each file, then :meth:`commit`, or :meth:`discard` on failure.
    """

    def __init__(self, out: str | os.PathLike, command: str):
        self.out, self.command = Path(out), command
        self.staged: dict[str, Path] = {}
        self._paused = False
        self.created = False

    @property
    def journal(self) -> Path:
        return self.out / f"{TEMP_PREFIX}{self.command}.commit.json"

    @property
    def manifest(self) -> Path:
        return self.out / f"{self.command}.manifest.json"

    def prepare(self) -> OutputSet:
        """Create ``out``, finish a commit a killed run left, remove stale staging files and
        check that ``out`` can be written, before any computation.

        Raises:
            OutputError: ``out`` cannot be created or written (naming it and why).
        """
        try:
            self.created = not self.out.exists()
            self.out.mkdir(parents=True, exist_ok=True)
            self.recover()
            clean_stale(self.out)
            unique_temporary(self.out / "probe").unlink()
        except OSError as exc:
            raise OutputError(exc.errno, f"--out {self.out}: cannot write there: "
                              f"{exc.strerror or exc}") from None
        return self

    def stage(self, name: str, write: Callable[[Path], object]) -> None:
        """Write the set's file ``name`` with ``write(staging_path)``.

        Raises:
            OutputError: the write failed (ENOSPC, ...): names the file and the reason.
        """
        if name in self.staged:
            self.staged.pop(name).unlink(missing_ok=True)
        final = self.out / name
        try:
            tmp = unique_temporary(final)
            self.staged[name] = tmp
            write(tmp)
        except OSError as exc:
            raise OutputError(exc.errno, f"cannot write {final}: {exc.strerror or exc}") \
                from None
        self._pause_for_tests()

    def _pause_for_tests(self) -> None:
        flag = os.environ.get(PAUSE_ENV)
        if flag and not self._paused:
            self._paused = True
            Path(flag).write_text(str(os.getpid()))
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                time.sleep(0.05)

    def discard(self) -> None:
        """Remove every staging file: nothing of this run is left, the old set is intact."""
        for tmp in self.staged.values():
            with contextlib.suppress(OSError):
                tmp.unlink()
        self.staged.clear()
        if self.created:  # made for this run and still empty: leave no trace
            with contextlib.suppress(OSError):
                self.out.rmdir()

    def commit(self) -> list[str]:
        """Make the staged files the set in ``out`` (see the module docstring); returns their
        names. SIGTERM and SIGINT wait until the renames are done (:func:`defer`)."""
        names = sorted(self.staged)
        if not names:
            return names
        entries = {}
        for name in names:
            _fsync(self.staged[name])
            entries[name] = {"staged": self.staged[name].name,
                             "sha256": _sha256(self.staged[name])}
        old = _read_manifest(self.manifest)
        dropped = sorted(set(old) - set(entries))
        with _critical(), _locked(self.out):
            _write_small(self.journal, {"command": self.command, "files": entries,
                                        "dropped": dropped})
            self.staged.clear()
            self._roll_forward()
            _COMMITTED.append(self.out)
        return names

    def recover(self) -> bool:
        """Roll forward a commit journal of this command in ``out``; True if there was one.
        Commits and recoveries in one directory take turns (an exclusive lock on it)."""
        with _critical(), _locked(self.out):
            return self._roll_forward()

    def _roll_forward(self) -> bool:
        try:
            journal = json.loads(self.journal.read_text())
        except FileNotFoundError:
            return False
        except (OSError, ValueError):
            self.journal.unlink(missing_ok=True)  # unreadable: written by no commit
            return False
        self.manifest.unlink(missing_ok=True)
        files = journal.get("files", {})
        for name, entry in files.items():
            staged = self.out / entry["staged"]
            if staged.exists():
                os.replace(staged, self.out / name)
        for name in journal.get("dropped", []):
            if name not in files:
                (self.out / name).unlink(missing_ok=True)
        _fsync(self.out)
        _write_small(self.manifest, {"command": self.command,
                                     "files": {n: e["sha256"] for n, e in files.items()}})
        self.journal.unlink()
        _fsync(self.out)
        return True


@contextlib.contextmanager
def _critical() -> Iterator[None]:
    """Within: a signal handler's exception is held (:func:`defer`) and raised on leaving,
    so a commit's renames are never cut short."""
    _CRITICAL["depth"] += 1
    try:
        yield
    finally:
        _CRITICAL["depth"] -= 1
        pending, _CRITICAL["pending"] = _CRITICAL["pending"], None
        if pending is not None and _CRITICAL["depth"] == 0:
            raise pending


def defer(exc: BaseException) -> bool:
    """For a signal handler: hold ``exc`` (SIGTERM's or Ctrl-C's exception) while a commit
    runs, to be raised when it ends; True if held (the handler then returns)."""
    if _CRITICAL["depth"] > 0:
        _CRITICAL["pending"] = _CRITICAL["pending"] or exc
        return True
    return False


@contextlib.contextmanager
def _locked(directory: Path) -> Iterator[None]:
    """An exclusive lock on ``directory`` (``flock`` on its descriptor) while inside."""
    import fcntl

    fd = os.open(directory, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _read_manifest(path: Path) -> dict[str, str]:
    try:
        return dict(json.loads(path.read_text()).get("files", {}))
    except (OSError, ValueError, AttributeError):
        return {}


def verify(out: str | os.PathLike, command: str) -> bool:
    """Whether ``out`` holds the complete set of ``command``: its manifest present and every
    file it names there with the recorded sha256."""
    out = Path(out)
    files = _read_manifest(out / f"{command}.manifest.json")
    if not files:
        return False
    try:
        return all(_sha256(out / name) == digest for name, digest in files.items())
    except OSError:
        return False


# -- the command line's session ----------------------------------------------------------------
@contextlib.contextmanager
def session(command: str) -> Iterator[None]:
    """Within: :func:`open_set` opens ``command``'s set; on a normal exit it is committed,
    on an exception (error, SIGTERM, Ctrl-C) discarded."""
    _ACTIVE.update(command=command, set=None)
    _COMMITTED.clear()
    try:
        yield
        current = _ACTIVE["set"]
        if current is not None:
            current.commit()
    except BaseException:
        current = _ACTIVE["set"]
        if current is not None:
            current.discard()
        raise
    finally:
        _ACTIVE.update(command=None, set=None)


def open_set(out: str | os.PathLike) -> OutputSet | None:
    """In a :func:`session`: the prepared set of the session's command in ``out`` (None
    outside a session)."""
    if _ACTIVE["command"] is None:
        return None
    current = _ACTIVE["set"]
    if current is None or current.out != Path(out):
        if current is not None:
            current.commit()
        current = OutputSet(out, _ACTIVE["command"]).prepare()
        _ACTIVE["set"] = current
    return current


def committed() -> list[Path]:
    """The directories whose sets the last :func:`session` committed (a signal that arrives
    during a commit is delivered after it: the outputs are then complete)."""
    return list(_COMMITTED)


def active() -> OutputSet | None:
    """The set the current session writes (None: none open)."""
    return _ACTIVE["set"]


def stage(path: str | os.PathLike, write: Callable[[Path], object]) -> None:
    """Write the file ``path`` with ``write(target)``: into the open set when ``path`` lies
    in its directory, else on its own through a unique temporary file and a rename."""
    path = Path(path)
    current = _ACTIVE["set"]
    if current is not None and path.parent.resolve() == current.out.resolve():
        current.stage(path.name, write)
        return
    tmp = unique_temporary(path)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
