"""A policy's files shipped to the machine that plays it, by content: what a Ray worker on another
machine needs to play a ``py:`` policy file, a ``py:`` package or an AMAT model file that only the
driver's disk holds.

:func:`bundle_for` packs the files (a ``py:`` file's whole folder, below it too, but hidden files and
folders, ``__pycache__`` and catmip's result folders below it, those with a ``run.json``; a package
policy's top package, found as the driver imports it; an AMAT's model file), each with its SHA-256.
On the worker, :func:`unpacked` writes them into a new folder for one chunk, in this user's private
folder, checks every file's SHA-256 as it arrived and as written, and removes the folder afterwards, so
that nothing a policy writes there lasts to the next chunk; :func:`played_from` gives the method that
plays from it (a package: :func:`importable` puts it first on the import path) and :func:`restored` puts
the driver's paths back into what the play recorded, so that the files written are the same wherever
the maps were played.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from catmip_rl.benchmark.replay import run_files
from catmip_rl.evaluation.methods import Method
from catmip_rl.evaluation.user_policy import parse_policy_source
from catmip_rl.store.shipped import model_file

__all__ = [
    "Bundle",
    "bundle_for",
    "files_bundle",
    "folder_files",
    "unpacked",
    "played_from",
    "importable",
    "restored",
    "run_bundle",
    "MAX_BUNDLE_BYTES",
]

MAX_BUNDLE_BYTES = 256 * 2**20
"""The most a bundle may hold: a policy's folder past it is refused in one line (give it a folder of
its own)."""
INSTALLED = ("catmip_env", "catmip_rl")
"""Packages every worker has installed: never sent."""


@dataclass(frozen=True)
class Bundle:
    """The files of one method: ``root`` the driver's folder they lie in, ``files`` (path below it, bytes,
    SHA-256), ``digest`` (SHA-256 over the paths and their SHA-256s) and ``entry``: the path below
    ``root`` of the file the method plays (a ``py:`` file, a model file; "" for a package)."""

    root: str
    files: tuple[tuple[str, bytes, str], ...]
    digest: str
    entry: str = ""


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def bundle_for(method: Method) -> Bundle | None:
    """The bundle that plays ``method`` elsewhere: a ``py:`` file's folder, a ``py:`` module's top package
    or an AMAT's model file; None for what every worker has (a planner, a reference row, catmip's own
    modules). ValueError for files past :data:`MAX_BUNDLE_BYTES` or a package this process cannot find."""
    if method.kind == "py" and parse_policy_source(method.target).is_file:
        file = Path(parse_policy_source(method.target).source).expanduser().resolve()
        root, paths, entry = file.parent, folder_files(file.parent), file.name
    elif method.kind == "py":  # py:package.module:F: its top package, found as this process imports it
        top = parse_policy_source(method.target).source.split(".")[0]
        if top in INSTALLED:
            return None
        spec = importlib.util.find_spec(top)
        if spec is None or spec.origin is None:
            raise ValueError(f"{method.name}: cannot find the package {top!r} here to send it to the workers")
        origin = Path(spec.origin).resolve()
        if spec.submodule_search_locations:  # a package: its folder, below its parent
            root, paths = origin.parent.parent, folder_files(origin.parent)
        else:  # a module file
            root, paths = origin.parent, [origin]
        entry = ""
    elif method.kind == "amat":
        file = model_file(Path(method.target)).resolve()
        root, paths, entry = file.parent, [file], file.name
    else:
        return None
    return replace(files_bundle(root, paths, method.name), entry=entry)


def folder_files(folder: Path) -> list[Path]:
    """The files a policy's folder ships: every file below it but hidden files and folders,
    ``__pycache__`` and catmip's result folders below it (those with a ``run.json``), which are not
    walked."""
    found = []
    for here, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d != "__pycache__")
        if Path(here) != folder and "run.json" in files:  # a result folder, not the policy's own
            dirs[:] = []
            continue
        found += [Path(here) / f for f in files if not f.startswith(".") and (Path(here) / f).is_file()]
    return sorted(found)


def files_bundle(root: Path, paths: list[Path], name: str) -> Bundle:
    """The bundle of ``paths`` (below ``root``), named ``name`` in its messages; ValueError past
    :data:`MAX_BUNDLE_BYTES`."""
    size = sum(p.stat().st_size for p in paths)
    if size > MAX_BUNDLE_BYTES:
        raise ValueError(
            f"{name}: its files below {root} hold {size / 2**20:.0f} MiB, past the "
            f"{MAX_BUNDLE_BYTES // 2**20} MiB a worker is sent: give the policy a folder of its own"
        )
    files = tuple(
        (p.relative_to(root).as_posix(), data, _sha(data)) for p in paths for data in [p.read_bytes()]
    )
    digest = _sha("\n".join(f"{rel} {sha}" for rel, _, sha in files).encode())
    return Bundle(str(root), files, digest)


@contextmanager
def unpacked(bundle: Bundle) -> Iterator[Path]:
    """Write ``bundle`` into a new folder of its own for the block (removed afterwards), in this user's
    private folder (mode 0700), checking every file's SHA-256 as it arrived and as written; the files are
    read-only. ValueError naming a file whose content is not the driver's or whose path leaves the
    folder; PermissionError if the private folder is not this user's."""
    base = Path(tempfile.gettempdir()) / f"catmip-shipped-{os.getuid()}"
    base.mkdir(mode=0o700, exist_ok=True)
    info = base.lstat()
    if base.is_symlink() or info.st_uid != os.getuid() or info.st_mode & 0o077:
        raise PermissionError(f"{base} is not this user's private folder (mode 0700): remove it")
    where = Path(tempfile.mkdtemp(prefix=bundle.digest[:12] + "-", dir=base))
    folder = where / (Path(bundle.root).name or "root")
    try:
        for rel, data, sha in bundle.files:
            if _sha(data) != sha:  # what arrived is not what the driver hashed
                raise ValueError(f"{rel} of {bundle.root}: its SHA-256 on this worker is not the driver's")
            path = (folder / rel).resolve()
            if not path.is_relative_to(folder.resolve()):
                raise ValueError(f"{rel} of {bundle.root} leaves the folder it is sent in")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
            path.chmod(0o444)
            if _sha(path.read_bytes()) != sha:
                raise ValueError(f"{rel} of {bundle.root}: its SHA-256 on this worker is not the driver's")
        folder.mkdir(parents=True, exist_ok=True)
        yield folder
    finally:
        shutil.rmtree(where, ignore_errors=True)


def played_from(bundle: Bundle, method: Method, folder: Path) -> Method:
    """``method`` playing from ``folder``, where ``bundle`` was unpacked: a ``py:`` file, or an AMAT's
    model file, at its place below the folder; a package policy as it is (:func:`importable`)."""
    if not bundle.entry:  # a package: imported from the folder
        return method
    if method.kind == "amat":
        return replace(method, target=str(folder / bundle.entry))
    source = parse_policy_source(method.target)
    return replace(method, target=method.target.replace(source.source, str(folder / bundle.entry), 1))


@contextmanager
def importable(folder: Path, bundle: Bundle) -> Iterator[None]:
    """A package policy's unpacked ``folder`` first on ``sys.path`` while the block runs (a policy's
    worker process imports from this process's path), its package's modules imported from elsewhere
    forgotten first; the path as it was afterwards."""
    tops = {rel.split("/")[0].removesuffix(".py") for rel, _, _ in bundle.files} - set(INSTALLED)
    for name in [m for m in sys.modules if m.split(".")[0] in tops]:
        del sys.modules[name]
    sys.path.insert(0, str(folder))
    try:
        yield
    finally:
        sys.path.remove(str(folder))


def restored(value: Any, bundle: Bundle, folder: Path) -> Any:
    """``value`` (what a play recorded: dicts, lists, strings) with the worker's ``folder`` of ``bundle``
    given back as the driver's ``bundle.root`` wherever it appears."""
    if isinstance(value, str):
        return value.replace(str(folder), bundle.root)
    if isinstance(value, dict):
        return {k: restored(v, bundle, folder) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(restored(v, bundle, folder) for v in value)
    return value


def run_bundle(entry: dict[str, Any], k: int) -> Bundle | None:
    """The files run ``k`` of a board's ``entry`` plays, below this folder (the clone's root, where an
    entry's paths start), with its ``py:`` policy file's whole folder; None for a run that plays none."""
    root = Path.cwd().resolve()
    run = entry["runs"][k]
    paths = {(root / f["file"]).resolve() for f in run_files(run)}
    source = run.get("source") or {}
    if str(run.get("spec", "")).startswith("py:") and source.get("file"):
        policy_folder = (root / source["file"]).resolve().parent
        if policy_folder != root and policy_folder.is_relative_to(root):  # never the whole clone
            paths |= set(folder_files(policy_folder))
    paths = {p for p in paths if p.is_file() and p.is_relative_to(root)}  # others: "not here" there
    return files_bundle(root, sorted(paths), entry["method"]) if paths else None
