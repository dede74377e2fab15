"""A policy's files shipped to the machine that plays it, by content: what a Ray worker on another
machine needs to play a ``py:`` policy file or an AMAT model file that only the driver's disk holds.

:func:`bundle_for` packs the files (a ``py:`` file's whole folder, below it too, but hidden files,
``__pycache__`` and catmip's result folders, those with a ``run.json``; an AMAT's model file), each with
its SHA-256; :func:`unpacked` writes them on the worker into a folder named by the bundle's digest,
checks every file's SHA-256 there, and gives the method that plays from that folder; :func:`restored`
puts the driver's paths back into what the play recorded, so that the files written are the same
wherever the maps were played. A package policy (``py:package.module:FACTORY``) sends its top package's
folder (or module file), found as the driver imports it; the worker puts the folder it unpacked first on
its import path while the chunk plays (:func:`importable`).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from catmip_rl.evaluation.methods import Method
from catmip_rl.evaluation.user_policy import parse_policy_source
from catmip_rl.store.shipped import model_file

__all__ = [
    "Bundle",
    "bundle_for",
    "files_bundle",
    "folder_files",
    "unpacked",
    "unpack",
    "importable",
    "restored",
    "MAX_BUNDLE_BYTES",
]

MAX_BUNDLE_BYTES = 256 * 2**20
"""The most a bundle may hold: a policy's folder past it is refused in one line (give it a folder of
its own)."""


@dataclass(frozen=True)
class Bundle:
    """The files of one method: ``root`` the driver's folder they lie in, ``files`` (path below it, bytes,
    SHA-256) and ``digest`` (SHA-256 over the paths and their SHA-256s)."""

    root: str
    files: tuple[tuple[str, bytes, str], ...]
    digest: str


def _hidden(rel: Path) -> bool:
    return any(part.startswith(".") or part == "__pycache__" for part in rel.parts)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def bundle_for(method: Method) -> Bundle | None:
    """The bundle that plays ``method`` elsewhere: a ``py:`` file's folder, a ``py:`` module's top package
    or an AMAT's model file; None for what every worker has (a planner, a reference row). ValueError for
    files past :data:`MAX_BUNDLE_BYTES` or a package this process cannot find."""
    if method.kind == "py" and parse_policy_source(method.target).is_file:
        root = Path(parse_policy_source(method.target).source).expanduser().resolve().parent
        paths = folder_files(root)
    elif method.kind == "py":  # py:package.module:F: its top package, found as this process imports it
        top = parse_policy_source(method.target).source.split(".")[0]
        spec = importlib.util.find_spec(top)
        if spec is None or spec.origin is None:
            raise ValueError(f"{method.name}: cannot find the package {top!r} here to send it to the workers")
        origin = Path(spec.origin).resolve()
        if spec.submodule_search_locations:  # a package: its folder, below its parent
            root, paths = origin.parent.parent, folder_files(origin.parent)
        else:  # a module file
            root, paths = origin.parent, [origin]
    elif method.kind == "amat":
        file = model_file(Path(method.target)).resolve()
        root, paths = file.parent, [file]
    else:
        return None
    return files_bundle(root, paths, method.name)


def folder_files(folder: Path) -> list[Path]:
    """The files a policy's folder ships: every file below it but hidden ones, ``__pycache__`` and
    catmip's result folders (those with a ``run.json``)."""
    results = [p.parent for p in folder.rglob("run.json")]
    return sorted(
        p
        for p in folder.rglob("*")
        if p.is_file()
        and not _hidden(p.relative_to(folder))
        and not any(p.is_relative_to(r) for r in results)
    )


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


def unpacked(bundle: Bundle, method: Method) -> Method:
    """Write ``bundle`` into this machine's folder for it (kept for the next chunk: named by its digest),
    check every file's SHA-256 there, and return ``method`` playing from it. ValueError naming a file
    whose content differs from what the driver sent."""
    folder = unpack(bundle)
    return replace(method, target=method.target.replace(bundle.root, str(folder), 1))


def unpack(bundle: Bundle) -> Path:
    """Write ``bundle`` into this machine's folder for it, checking every file (:func:`unpacked`);
    returns the folder."""
    folder = _folder(bundle)
    for rel, data, sha in bundle.files:
        if _sha(data) != sha:  # what arrived is not what the driver hashed
            raise ValueError(f"{rel} of {bundle.root}: its SHA-256 on this worker is not the driver's")
        path = folder / rel
        if not path.is_file() or _sha(path.read_bytes()) != sha:
            path.parent.mkdir(parents=True, exist_ok=True)
            part = path.with_name(f".{path.name}.{os.getpid()}.part")
            part.write_bytes(data)
            os.replace(part, path)
        if _sha(path.read_bytes()) != sha:
            raise ValueError(f"{rel} of {bundle.root}: its SHA-256 on this worker is not the driver's")
    return folder


@contextmanager
def importable(bundle: Bundle) -> Iterator[Path]:
    """Unpack ``bundle`` (a package policy's) and put its folder first on ``sys.path`` while the block
    runs (a policy's worker process imports from this process's path), forgetting any module of the
    package imported from elsewhere; the path as it was afterwards."""
    folder = unpack(bundle)
    tops = {rel.split("/")[0].removesuffix(".py") for rel, _, _ in bundle.files}
    for name in [m for m in sys.modules if m.split(".")[0] in tops]:
        del sys.modules[name]
    sys.path.insert(0, str(folder))
    try:
        yield folder
    finally:
        sys.path.remove(str(folder))


def _folder(bundle: Bundle) -> Path:
    return Path(tempfile.gettempdir()) / "catmip-shipped" / bundle.digest / Path(bundle.root).name


def restored(value: Any, bundle: Bundle) -> Any:
    """``value`` (what a play recorded: dicts, lists, strings) with the worker's folder of ``bundle`` given
    back as the driver's ``bundle.root``."""
    here = str(_folder(bundle))
    if isinstance(value, str):
        return bundle.root + value[len(here) :] if value.startswith(here) else value
    if isinstance(value, dict):
        return {k: restored(v, bundle) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(restored(v, bundle) for v in value)
    return value
