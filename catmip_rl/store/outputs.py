"""Output folders and files that hold one run's results or none: whether a path may be written without
losing anything (:func:`check_new_dir`, :func:`check_new_file`: asked here, once per output), one writer
at a time, results written aside and moved in at the end, and a record of the run that wrote them.

Every command that writes results holds its output while it runs (:class:`OutputLock`, an advisory OS
lock that the kernel drops however the process ends): a second writer is refused with one line naming
the first. A result folder is written into a hidden staging folder and moved in at the end, its record
``run.json`` (the run's id, command and each file's SHA-256) last (:func:`commit_results`), so that a
reader can tell a folder of one run's files (:func:`check_record`) from one that a killed or second
writer left mixed. ``--force`` replaces earlier results: the result folders inside the output are
removed first (:func:`remove_results`); what a killed writer left (temporary files, staging folders) is
removed by the next writer (:func:`remove_debris`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import socket
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from catmip_rl.store.files import atomic_write_text

__all__ = [
    "OutputInUse",
    "OutputLock",
    "RECORD",
    "RUN_ID",
    "commit_results",
    "check_record",
    "remove_results",
    "remove_debris",
    "holding",
    "output_folder",
    "output_file",
    "staging_dir",
    "first_missing",
    "check_new_dir",
    "check_new_file",
    "check_not_dangling",
]

RECORD = "run.json"
"""The record a result folder ends with: which run wrote it, and the SHA-256 of each of its files."""
RECORD_FORMAT = "catmip-results/1"
RUN_ID = uuid.uuid4().hex
"""This process's run id, written in every record it leaves."""
STAGING = ".incoming-"
RESULT_MARKERS = (RECORD, "summary.json")
"""A folder holding one of these is a result folder (``summary.json``: one written before records)."""


class OutputInUse(OSError):
    """Another live process writes to the output."""


class OutputLock:
    """The exclusive hold of an output by this process: ``flock`` on ``lock_path``, which names the
    holder (process id, command, start) for the refusal. The kernel drops the lock when the process ends,
    however it ends, so a dead writer never leaves a stale lock. ``keep_file``: the lock file stays when
    released (a training run dir); otherwise it is removed, and an acquirer that locked a file since
    removed or replaced tries again, so that two processes never hold two files of one name."""

    def __init__(
        self,
        lock_path: str | Path,
        what: str,
        advice: str = "wait for it to end or stop it",
        keep_file: bool = False,
    ) -> None:
        self.path = Path(lock_path)
        self.what, self.advice, self.keep_file = what, advice, keep_file
        self._fd: int | None = None

    def acquire(self) -> OutputLock:
        """Hold the output, or raise :class:`OutputInUse` naming the process that holds it."""
        import fcntl  # POSIX: Linux and macOS

        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 4096, 0).decode(errors="replace").strip() or "another process"
                os.close(fd)
                raise OutputInUse(f"{self.what} is in use by {holder}; {self.advice}") from None
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # the previous holder removed the file we locked: lock the new one
        os.ftruncate(fd, 0)
        holder = f"process {os.getpid()} ({_command()}, since {time.strftime('%Y-%m-%d %H:%M:%S')})\n"
        os.pwrite(fd, holder.encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        if not self.keep_file:
            self.path.unlink(missing_ok=True)  # before closing: no one else can hold it yet
        os.close(self._fd)  # closing the last descriptor drops the flock
        self._fd = None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def holding(out: str | Path, what: str = "--out", is_file: bool = False) -> OutputLock:
    """The lock of an output folder (``OUT/.lock``) or, ``is_file``, of an output file
    (``.NAME.lock`` beside it), named ``what OUT`` in refusals."""
    out = Path(out)
    lock = out.parent / f".{out.name}.lock" if is_file else out / ".lock"
    return OutputLock(lock, f"{what} {out}")


@contextmanager
def output_folder(
    out: str | Path,
    what: str = "--out",
    force: bool = False,
    keep: bool = False,
    advice: str = "",
    replace_results: bool = True,
) -> Iterator[Path]:
    """Hold output folder ``out`` while the block writes in it: refused (one line) if another process
    holds it, or, checked again once held, if it is not empty. ``force``: write into it, its earlier
    result folders removed first (unless not ``replace_results``); ``keep``: what it holds stays (a
    suite's runs to read back, a bench's other figures). What a killed writer left is removed. A folder
    this call created is removed again if the block fails before writing anything."""
    out = Path(out)
    if out.is_symlink():
        raise ValueError(
            f"{what} {out} is a symbolic link (to {os.readlink(out)}): give the folder itself (nothing is "
            "written through a link)"
        )
    check_new_dir(out, what, force=force or keep, advice=advice, ignore=(".lock",))  # before creating it
    created = first_missing(out)
    lock = holding(out, what)
    try:
        lock.acquire()
        check_new_dir(out, what, force=force or keep, advice=advice, ignore=(".lock",))  # a writer since
        remove_debris(out)
        if force and replace_results and not keep:
            remove_results(out)
        yield out
    except BaseException:
        lock.release()
        if created is not None and not any(p.is_file() for p in created.rglob("*")):
            shutil.rmtree(created, ignore_errors=True)
        raise
    lock.release()


@contextmanager
def output_file(
    path: str | Path, what: str = "--out", force: bool = False, suffixes: tuple[str, ...] = ()
) -> Iterator[Path]:
    """Hold output file ``path`` (a ``.NAME.lock`` beside it) while the block writes it: refused if
    another process holds it or, checked again once held, if it exists (``force``: it is replaced)."""
    check_new_file(path, what, force=force, suffixes=suffixes)
    path = Path(path)
    with holding(path, what, is_file=True):
        check_new_file(path, what, force=force, suffixes=suffixes)  # a writer since
        yield path


def first_missing(path: Path) -> Path | None:
    """The outermost folder of ``path`` (itself included) that does not exist yet: what ``mkdir(parents=
    True)`` creates; None if ``path`` exists."""
    missing = None
    for p in (path, *path.parents):
        if p.exists():
            break
        missing = p
    return missing


def _command() -> str:
    return " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv and sys.argv[0] else "python"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def staging_dir(out: str | Path) -> Path:
    """A fresh hidden folder inside ``out`` to write a run's results in before :func:`commit_results`."""
    path = Path(out) / f"{STAGING}{os.getpid()}-{uuid.uuid4().hex[:8]}"
    path.mkdir(parents=True)
    return path


def commit_results(staging: Path) -> Path:
    """Move the files written in ``staging`` into its parent folder, replacing files of those names, then
    write the record (this run's id, command, time and each file's SHA-256) last; remove ``staging``.
    Returns the result folder."""
    out = staging.parent
    files = sorted(p.name for p in staging.iterdir() if p.is_file())
    record = {
        "format": RECORD_FORMAT,
        "run_id": RUN_ID,
        "command": _command(),
        "process": os.getpid(),
        "host": socket.gethostname(),
        "written": time.strftime("%Y-%m-%d %H:%M:%S"),
        "files": {name: _sha256(staging / name) for name in files},
    }
    (out / RECORD).unlink(missing_ok=True)  # the folder is not one run's until the new record is in
    for name in sorted(files, key=lambda n: n == "summary.json"):  # summary last: a folder with it is whole
        os.replace(staging / name, out / name)
    atomic_write_text(out / RECORD, json.dumps(record, indent=1))
    shutil.rmtree(staging, ignore_errors=True)
    return out


def check_record(folder: str | Path) -> dict | None:
    """The record of result folder ``folder``, checked: every file it lists is there with its SHA-256.
    None for a folder written before records existed; ValueError naming the folder for a record that is
    not one, or files that are missing or another run's (a folder mixed by two writers, or edited)."""
    folder = Path(folder)
    path = folder / RECORD
    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text())
        files = record["files"]
        ok = record.get("format") == RECORD_FORMAT and isinstance(record.get("run_id"), str)
        ok = ok and isinstance(files, dict) and all(isinstance(v, str) for v in files.values())
    except (ValueError, KeyError, TypeError, OSError):
        ok = False
    if not ok:
        raise ValueError(f"{path} is not a catmip results record; the folder cannot be trusted as one run's")
    bad = [
        name
        for name, digest in files.items()
        if not (folder / name).is_file() or _sha256(folder / name) != digest
    ]
    if bad:
        raise ValueError(
            f"{folder} does not hold one run's results: {', '.join(sorted(bad))} missing or not written by "
            f"the run of its {RECORD} (a second writer, an interrupted one, or an edit); play it again"
        )
    return record


def remove_results(out: str | Path) -> list[Path]:
    """Remove the result folders inside ``out`` (``out`` itself and any folder below holding a record or a
    ``summary.json``: the results of an earlier run, which ``--force`` replaces); other files stay.
    Returns what was removed."""
    out = Path(out)
    removed = []
    if not out.is_dir():
        return removed
    for marker in RESULT_MARKERS:
        for path in sorted(out.rglob(marker)):
            folder = path.parent
            if folder == out:
                for name in _record_files(out) | {RECORD}:
                    (out / name).unlink(missing_ok=True)
                    removed.append(out / name)
            elif folder.exists():
                shutil.rmtree(folder)
                removed.append(folder)
    return removed


def _record_files(folder: Path) -> set[str]:
    """The files a result folder's record lists, or the files an evaluation writes (no record)."""
    try:
        return set(json.loads((folder / RECORD).read_text())["files"])
    except (OSError, ValueError, KeyError, TypeError):
        return {"episodes.json", "episodes.csv", "curve.csv", "curve.png", "summary.json"}


def remove_debris(out: str | Path) -> None:
    """Remove what a killed writer left in ``out`` and below: temporary files of atomic writes and
    staging folders (call it holding ``out``'s lock: a live writer's are then none)."""
    out = Path(out)
    if not out.is_dir():
        return
    for path in sorted(out.rglob(f"{STAGING}*")):
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
    for path in out.rglob(".*.tmp*"):
        if path.is_file():
            path.unlink(missing_ok=True)


def check_new_dir(
    path: str | Path, what: str, force: bool = False, advice: str = "", ignore: tuple[str, ...] = ()
) -> Path:
    """Raise unless ``path`` can become an output folder without overwriting anything: it does not exist
    (and can be created) or is an empty folder (but for entries named in ``ignore``); ``force`` accepts a
    folder with files too. ``what`` names the path in messages (a flag: ``--out``); ``advice`` replaces
    the default "pick a new folder or pass --force" hint."""
    path = Path(path)
    check_not_dangling(path, what)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{what} {path} is a file, not a folder")
    if path.is_dir() and not force:
        entries = sorted(p.name for p in path.iterdir() if p.name not in ignore)
        if entries:
            shown = ", ".join(entries[:4]) + (", ..." if len(entries) > 4 else "")
            hint = advice or "pick a new folder, or pass --force to write into it"
            raise FileExistsError(f"{what} {path} is not empty ({shown}); {hint}")
    _check_creatable(path, what)
    return path


def check_new_file(path: str | Path, what: str, force: bool = False, suffixes: tuple[str, ...] = ()) -> Path:
    """Raise unless ``path`` can be written as a new file: not a folder, ending in one of ``suffixes``
    (if given), not there yet (``force``: overwrite it), in a folder that exists or can be created."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{what} {path} is a folder; give a file path")
    if suffixes and path.suffix.lower() not in suffixes:
        raise ValueError(f"{what} {path}: the file name must end in {' or '.join(suffixes)}")
    if os.path.lexists(path) and not force:  # a dangling symbolic link too
        link = f" (a symbolic link to {os.readlink(path)})" if path.is_symlink() else ""
        raise FileExistsError(f"{what} {path} exists{link}; pick a new name, or pass --force to overwrite it")
    _check_creatable(path.parent, what)
    return path


def _check_creatable(folder: Path, what: str) -> None:
    """``folder`` exists or can be created: its nearest existing ancestor is a folder we may write in."""
    p = folder.absolute()
    while not p.exists():
        check_not_dangling(p, what)
        p = p.parent
    if not p.is_dir():
        raise NotADirectoryError(f"{what} {folder}: {p} is a file, so the folder cannot be created")
    if not os.access(p, os.W_OK | os.X_OK):
        raise PermissionError(f"{what} {folder}: no permission to write in {p}")


def check_not_dangling(path: Path, what: str) -> None:
    """A symbolic link to nothing cannot become a folder (mkdir meets the link): refuse it up front."""
    if path.is_symlink() and not path.exists():
        raise FileExistsError(
            f"{what} {path} is a symbolic link to {os.readlink(path)}, which does not exist; remove the link "
            "or pick another path"
        )
