"""Output folders: checked before any computing, written whole or not at all.

:func:`check_out_dir` refuses an unusable output folder before anything is computed.
:func:`publish` (with :func:`staged`) replaces a set of files so that a reader, a second writer, an
error, a Ctrl-C or a killed process never leaves a mix of two runs: files are rendered into a stage
folder ``<out>/.tmp-<label>.<pid>.<host>.<random>/``; under an exclusive ``fcntl.flock`` on
``<out>/.oslbench.lock`` the writer rolls back a swap a killed writer left half done and removes
stale temporary entries (owner dead on this host), writes the journal ``<out>/.oslbench.journal``,
keeps the previous versions in a backup folder, moves the new files in (the last one last), and
deletes the journal: the commit. On an error it restores the previous versions and re-raises.

The manifest ``<out>/.oslbench.manifest.json`` records each writer's files and their SHA-256. A file
the writer's previous publish recorded, this one does not write, and that still holds what was
written is stale and removed (with a warning of the ``bench.outdir`` logger); every other file stays.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import logging
import os
import re
import shutil
import socket
import tempfile
import time
from pathlib import Path, PurePosixPath
from typing import IO, Callable, Iterable, Iterator

from bench.errors import OutDirError

try:  # POSIX; elsewhere writers are not serialised
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

__all__ = ["check_out_dir", "publish", "staged"]

#: The lock file, inside the output folder.
LOCK_NAME = ".oslbench.lock"
#: The journal of a swap in progress, inside the output folder.
JOURNAL_NAME = ".oslbench.journal"
#: The files each writer published, with their SHA-256, inside the output folder.
MANIFEST_NAME = ".oslbench.manifest.json"
#: Seconds a writer waits for another writer's lock (a swap takes milliseconds).
LOCK_TIMEOUT = 120.0
#: Temporary names in an output folder start with this.
TMP_PREFIX = ".tmp-"
JOURNAL_FORMAT = 1
_POLL_S = 0.05
_HOST = hashlib.sha256(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:8]
_NO_LOCKING = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}
_log = logging.getLogger(__name__)


def check_out_dir(path) -> Path:
    """Check that ``path`` is a folder this process can write into (create it if missing).

    Parameters
    ----------
    path : str or path-like
        The output folder (``--out``, as the messages name it).

    Returns
    -------
    Path

    Raises
    ------
    OutDirError
        The path is empty, a file, cannot be created, or is not writable (the message names it).
    """
    try:
        text = os.fsdecode(path)
    except TypeError:
        raise OutDirError(f"--out: expected a folder path, got {path!r}") from None
    if text == "":
        raise OutDirError("--out: an empty path is not a folder")
    folder = Path(text)
    if folder.exists() and not folder.is_dir():
        kind = "is a file, not a folder" if folder.is_file() else "exists and is not a folder"
        raise OutDirError(f"--out {text!r}: {kind}")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (OSError, ValueError) as exc:  # a parent that is a file, no permission, a NUL byte
        raise OutDirError(f"--out {text!r}: cannot create the folder ({_why(exc)})") from None
    try:
        fd, probe = tempfile.mkstemp(prefix=_tmp_prefix("probe"), dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutDirError(f"--out {text!r}: the folder is not writable ({_why(exc)})") from None
    return folder


def _why(exc: BaseException) -> str:
    """The reason an OS error gives (its strerror), else its message or type."""
    return getattr(exc, "strerror", None) or str(exc) or type(exc).__name__


def _tmp_prefix(label: str) -> str:
    """``.tmp-<label>.<pid>.<host>.``: the owner recorded in the name."""
    label = re.sub(r"[^A-Za-z0-9_-]", "_", label) or "x"
    return f"{TMP_PREFIX}{label}.{os.getpid()}.{_HOST}."


def _alive(pid: int) -> bool:
    """Whether a process with this id runs on this host."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        pass
    return True


def _stale(path: Path) -> bool:
    """A temporary entry whose owner (:func:`_tmp_prefix`) is dead on this host, or a folder naming no owner."""
    parts = path.name[len(TMP_PREFIX):].split(".")
    if len(parts) != 4 or not parts[1].isdigit():
        return path.is_dir() and not path.is_symlink()
    return parts[2] == _HOST and not _alive(int(parts[1]))


@contextlib.contextmanager
def staged(out_dir, label: str = "write") -> Iterator[Path]:
    """A fresh stage folder inside ``out_dir`` for rendering files; removed on exit, whatever happens.

    Parameters
    ----------
    out_dir : path
        The output folder (must exist).
    label : str
        A word in the folder's name (e.g. ``"report"``).

    Yields
    ------
    Path
        The stage folder; render into it, then call :func:`publish`.
    """
    stage = Path(tempfile.mkdtemp(prefix=_tmp_prefix(label), dir=out_dir))
    try:
        yield stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)


@contextlib.contextmanager
def locked(out_dir, timeout: float = LOCK_TIMEOUT) -> Iterator[None]:
    """Hold the exclusive lock of ``out_dir`` (``fcntl.flock`` on ``<out>/.oslbench.lock``); OutDirError when
    the lock file cannot be opened or another writer holds it for ``timeout`` seconds.

    The holder deletes the lock file before releasing it, so that no empty file stays in a report folder; a
    waiter that then gets the lock of the deleted file sees that the path no longer names its file and
    opens the lock again.
    """
    out = Path(out_dir)
    lock = out / LOCK_NAME
    deadline = time.monotonic() + timeout
    while True:
        fd = _open_lock(out, lock)
        try:
            stale = _acquire(fd, out, lock, deadline, timeout) and not _same_file(fd, lock)
        except BaseException:
            os.close(fd)
            raise
        if not stale:
            break
        os.close(fd)  # the previous holder deleted this lock file: lock the one the path names now
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            if _same_file(fd, lock):
                lock.unlink()  # still held: nobody can lock it between the deletion and the release
        os.close(fd)  # releases the lock


def _open_lock(out: Path, lock: Path) -> int:
    try:
        return os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        raise OutDirError(f"{out}: cannot open the lock file {LOCK_NAME} ({_why(exc)})") from None


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the file open as ``fd``."""
    try:
        st, cur = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) == (cur.st_dev, cur.st_ino)


def _acquire(fd: int, out: Path, lock: Path, deadline: float, timeout: float) -> bool:
    """``flock`` the open lock file, waiting until ``deadline``; False where the file system cannot lock (writes
    then go unserialised)."""
    if fcntl is None:
        return False
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= deadline:
                raise OutDirError(
                    f"{out}: another oslbench process has been writing into this folder for more "
                    f"than {timeout:g} s (it holds {lock}); wait for it to finish or stop it, then "
                    "run again") from None
            time.sleep(_POLL_S)
        except OSError as exc:
            if exc.errno in _NO_LOCKING:  # a file system without flock: write unserialised
                return False
            raise OutDirError(f"{out}: cannot lock {LOCK_NAME} ({_why(exc)})") from None


def atomic_write(path, write: Callable[[IO[bytes]], None], *, prefix: str = TMP_PREFIX, sync: bool = False) -> None:
    """Write ``path`` whole or not at all: ``write(fh)`` into a temporary file beside it (fsync'ed when
    ``sync``), then rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=prefix, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            if sync:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:  # KeyboardInterrupt included: leave no temporary file behind
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _rollback(out: Path, doc: dict) -> list[str]:
    """Undo a swap described by a journal; returns the problems (empty: fully restored)."""
    backup = out / doc["backup"]
    problems: list[str] = []
    for entry in reversed(doc["entries"]):
        rel = entry["path"]
        dst, old = out / rel, backup / rel
        try:
            if os.path.lexists(old):
                os.replace(old, dst)  # the previous version back (over the new one, if it came in)
            elif entry["new"] and not entry["old"] and os.path.lexists(dst):
                os.unlink(dst)  # a new file that had no previous version
        except OSError as exc:
            problems.append(f"{rel}: {_why(exc)}")
    if not problems:
        shutil.rmtree(backup, ignore_errors=True)
    return problems


def recover(out_dir) -> None:
    """Roll back a swap a killed writer left half done, and remove stale temporary entries, holding
    :func:`locked`. OutDirError when the journal is unreadable or a file could not be restored (the journal
    is kept for the next writer)."""
    out = Path(out_dir)
    journal = out / JOURNAL_NAME
    if os.path.lexists(journal):
        try:
            doc = json.loads(journal.read_text(encoding="utf-8"))
            if doc.get("format") != JOURNAL_FORMAT:
                raise ValueError(f"unknown format {doc.get('format')!r}")
            for e in doc["entries"]:
                _relpath(e["path"])
            _relpath(doc["backup"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise OutDirError(f"{out}: the journal {JOURNAL_NAME} of an interrupted write is unreadable "
                              f"({_why(exc)}); check the folder's files, then delete the journal") from None
        problems = _rollback(out, doc)
        if problems:
            raise OutDirError(f"{out}: could not undo the interrupted write recorded in {JOURNAL_NAME} "
                              f"({'; '.join(problems[:3])}); the previous versions are in {doc['backup']}")
        journal.unlink()
    for entry in out.iterdir():
        if entry.name.startswith(TMP_PREFIX) and _stale(entry):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    entry.unlink()


def _relpath(rel: str) -> str:
    """``rel`` if it is a plain relative POSIX path (no absolute path, no ".."), else ValueError."""
    p = PurePosixPath(rel)
    if not rel or p.is_absolute() or ".." in p.parts or str(p) != rel or rel == ".":
        raise ValueError(f"not a plain relative path: {rel!r}")
    return rel


def _keep_old(src: Path, dst: Path, *, move: bool) -> None:
    """Keep the previous version ``src`` at ``dst``: moved, or hard-linked (readable until replaced) unless ``move``."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if not move and src.is_file() and not src.is_symlink():
        with contextlib.suppress(OSError):  # no hard links here (EXDEV, EPERM, ...): move it
            os.link(src, dst)
            return
    os.replace(src, dst)


def publish(out_dir, stage_dir, files: Iterable[str], *, writer: str | None = None,
            timeout: float = LOCK_TIMEOUT) -> list[Path]:
    """Move rendered files from ``stage_dir`` into ``out_dir``, all of them or none.

    Parameters
    ----------
    out_dir : path
        The output folder (must exist).
    stage_dir : path
        A folder inside ``out_dir`` holding the new files (:func:`staged`).
    files : iterable of str
        The new files as relative POSIX paths, in the order they are moved in (the last one last).
    writer : str, optional
        Record ``files`` in the manifest under this name and delete this writer's stale files.
    timeout : float
        Seconds to wait for another writer's lock.

    Returns
    -------
    list of Path
        The published paths, in order.

    Raises
    ------
    OutDirError
        No lock in time, or an earlier interrupted write could not be undone; also when the
        restore after an interrupted swap fails (the journal is kept).
    ValueError
        A path in ``files`` is absolute, climbs out, repeats, or was not rendered.
    """
    out, stage = Path(out_dir), Path(stage_dir)
    files = [_relpath(f) for f in files]
    if len(set(files)) != len(files):
        raise ValueError(f"publish: a file is listed twice in {files}")
    for rel in files:
        if not (stage / rel).is_file():
            raise ValueError(f"publish: {rel!r} was not rendered into {stage}")
    with locked(out, timeout):
        recover(out)
        stale = []
        if writer is not None:
            stale = _update_manifest(out, stage, files, writer)
            files = [MANIFEST_NAME, *files]
        backup, doc = _journal(out, stale, files)
        _swap(out, stage, doc, backup)
        shutil.rmtree(backup, ignore_errors=True)
    if stale:
        _log.warning("%s: removed %d file(s) that an earlier run of this suite wrote and this one does not: %s",
                     out, len(stale), ", ".join(stale))
    return [out / rel for rel in files if rel != MANIFEST_NAME]


def _journal(out: Path, stale: list[str], files: list[str]) -> tuple[Path, dict]:
    """A fresh backup folder and the journal of the swap (stale and new files), written before anything moves."""
    backup = Path(tempfile.mkdtemp(prefix=_tmp_prefix("backup"), dir=out))
    entries = ([{"path": rel, "old": True, "new": False} for rel in stale]
               + [{"path": rel, "old": os.path.lexists(out / rel), "new": True} for rel in files])
    doc = {"format": JOURNAL_FORMAT, "pid": os.getpid(), "host": _HOST, "backup": backup.name, "entries": entries}
    try:
        atomic_write(out / JOURNAL_NAME, lambda fh: fh.write(json.dumps(doc).encode()), prefix=_tmp_prefix("journal"),
                     sync=True)
    except BaseException:
        shutil.rmtree(backup, ignore_errors=True)
        raise
    return backup, doc


def sha_file(path) -> str | None:
    """SHA-256 of a file's bytes (None when it cannot be read)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _update_manifest(out: Path, stage: Path, files: list[str], writer: str) -> list[str]:
    """Write the new manifest into ``stage``; return ``writer``'s stale files (none if the manifest is unreadable)."""
    try:
        writers = dict(json.loads((out / MANIFEST_NAME).read_text(encoding="utf-8"))["writers"])
    except (OSError, ValueError, KeyError, TypeError):
        writers = {}
    try:
        previous = {_relpath(rel): str(sha) for rel, sha in writers.get(writer, {}).items()}
    except (ValueError, TypeError, AttributeError):
        previous = {}
    new = set(files)
    stale, kept = [], []
    for rel, sha in sorted(previous.items()):
        path = out / rel
        if rel not in new and path.is_file() and not path.is_symlink():
            (stale if sha_file(path) == sha else kept).append(rel)
    if kept:
        _log.warning("%s: kept %s: written by an earlier run of this suite, changed since", out, ", ".join(kept))
    writers[writer] = {rel: sha_file(stage / rel) for rel in files}
    (stage / MANIFEST_NAME).write_text(json.dumps({"format": 1, "writers": writers}, indent=1, sort_keys=True),
                                       encoding="utf-8")
    return stale


def _swap(out: Path, stage: Path, doc: dict, backup: Path) -> None:
    """Move the journal's entries and commit by deleting the journal; on any error roll back and re-raise."""
    try:
        for e in doc["entries"]:
            rel = e["path"]
            if e["old"]:
                _keep_old(out / rel, backup / rel, move=not e["new"])
            if e["new"]:
                (out / rel).parent.mkdir(parents=True, exist_ok=True)
                os.replace(stage / rel, out / rel)
        (out / JOURNAL_NAME).unlink()  # the commit
    except BaseException as exc:
        problems = _rollback(out, doc)
        if problems:
            raise OutDirError(
                f"{out}: writing failed ({type(exc).__name__}: {exc}) and the previous files could not "
                f"all be restored ({'; '.join(problems[:3])}); they are in {backup.name}, and the next "
                "run restores them first") from exc
        with contextlib.suppress(OSError):
            (out / JOURNAL_NAME).unlink()
        raise
