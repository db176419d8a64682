"""Where a store lives: a local folder or an fsspec URL such as ``s3://bucket/paper.zarr``.

Zarr opens both kinds from the same string. This module does the rest for a
build: it checks a URL and its fsspec backend before anything is written
(:func:`store_location`), and performs the few path operations of a build
(is there a store, what is in it, clear it, remove half-written files)
through fsspec when the store is a URL.

Credentials and endpoints are not part of the store string. Every process of
a build (driver and workers) reads them from its environment through the
backend's own configuration: for s3fs ``AWS_ACCESS_KEY_ID``,
``AWS_SECRET_ACCESS_KEY``, ``AWS_ENDPOINT_URL`` (MinIO, Ceph, other
S3-compatible stores), ``AWS_PROFILE``; for any backend fsspec's
``FSSPEC_<PROTOCOL>_<OPTION>`` variables. Workers must see the same variables
as the driver.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from shared.errors import InputError
from shared.location import is_url

__all__ = [
    "StoreURLError",
    "is_url",
    "store_location",
    "filesystem",
    "is_local",
    "exists",
    "entries",
    "clear",
    "remove_partials",
    "remove",
    "size",
]

#: Protocols whose data live inside one process: workers in other processes would each see their own.
PROCESS_LOCAL = frozenset({"memory"})

#: Protocols of the local file system, turned into plain paths.
LOCAL_PROTOCOLS = frozenset({"file", "local"})


class StoreURLError(InputError):
    """A store URL is malformed, its fsspec backend is missing, or it cannot be shared by workers."""


def _protocol(url: str) -> str:
    return url.split("::")[-1].split("://", 1)[0]


def store_location(store: str | Path, for_workers: bool = False) -> str:
    """The canonical form of ``store``: an absolute local path, or a URL whose backend is installed.

    ``file://`` and ``local://`` URLs become plain paths (Zarr's local store
    writes atomically and makes parent folders). A relative path is made
    absolute, so that workers started in another folder write to the same
    store. ``for_workers`` marks a store written by worker processes (a build):
    a process-local filesystem (``memory://``) is then refused, since each
    worker would write into its own copy.

    Raises
    ------
    StoreURLError
        Unknown protocol, backend not installed (naming the package to install),
        no path inside the bucket, or a process-local store for workers.
    """
    if is_url(store):
        protocol = _protocol(store)
        if not store.rsplit("://", 1)[1].strip("/"):
            raise StoreURLError(f"store {store}: no path after {protocol}://, e.g. {protocol}://bucket/name.zarr")
        if "::" not in store and protocol in LOCAL_PROTOCOLS:
            store = filesystem(store)[1]
    if not is_url(store):
        return os.path.abspath(Path(store).expanduser())
    url = store.rstrip("/")
    if for_workers and protocol in PROCESS_LOCAL:
        raise StoreURLError(
            f"store {url}: {protocol}:// lives inside one process and is not shared with the Dask workers; "
            "use a folder on a shared file system or an object store URL (e.g. s3://bucket/name.zarr)"
        )
    fs, path = filesystem(url)
    if "/" not in path.strip("/"):
        raise StoreURLError(
            f"store {url}: give a prefix inside the bucket, e.g. {protocol}://{path.strip('/')}/name.zarr "
            "(a store at the bucket root would be cleared whole by --force)"
        )
    return url


def filesystem(url: str):
    """``(fsspec filesystem, path inside it)`` of a store URL, with errors that say what to install."""
    import fsspec

    try:
        return fsspec.url_to_fs(url)
    except ImportError as exc:  # fsspec knows the protocol, its package is missing
        raise StoreURLError(f"store {url}: the fsspec backend of {_protocol(url)}:// is not installed: {exc}") from exc
    except ValueError as exc:  # "Protocol not known", malformed URL
        raise StoreURLError(f"store {url}: not a usable fsspec URL: {exc}") from exc


def is_local(store: str) -> bool:
    """``True`` when ``store`` (a :func:`store_location`) is a local folder, not a URL."""
    return not is_url(store)


def _fs_root(store: str):
    fs, root = filesystem(store)
    fs.invalidate_cache(root)  # listings cached by this process may predate other processes' writes
    return fs, root.rstrip("/")


def exists(store: str, key: str = "") -> bool:
    """Whether ``key`` (e.g. ``"zarr.json"``) exists in the store, or the store itself when ``key`` is empty."""
    if is_local(store):
        return (Path(store) / key).exists()
    fs, root = _fs_root(store)
    return fs.exists(f"{root}/{key}" if key else root)


def remove(store: str, key: str) -> None:
    """Delete the file ``key`` (e.g. ``"zarr.json"``) of the store, if it is there."""
    if is_local(store):
        (Path(store) / key).unlink(missing_ok=True)
        return
    fs, root = _fs_root(store)
    if fs.exists(f"{root}/{key}"):
        fs.rm_file(f"{root}/{key}")


def entries(store: str) -> list[str]:
    """Names directly inside the store (``[]`` when it does not exist)."""
    if is_local(store):
        path = Path(store)
        return sorted(p.name for p in path.iterdir()) if path.is_dir() else []
    fs, root = _fs_root(store)
    try:
        return sorted(name.rstrip("/").rsplit("/", 1)[-1] for name in fs.ls(root, detail=False))
    except FileNotFoundError:
        return []


def size(store: str) -> int:
    """Bytes of every file (object) in the store."""
    if is_local(store):
        return sum(p.stat().st_size for p in Path(store).rglob("*") if p.is_file())
    fs, root = _fs_root(store)
    return int(fs.du(root))


def clear(store: str, keep: frozenset[str] | set[str] = frozenset()) -> None:
    """Delete everything in the store except the top-level entries named in ``keep`` (the lock)."""
    if is_local(store):
        for p in Path(store).iterdir():
            if p.name in keep:
                continue
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
        return
    fs, root = _fs_root(store)
    doomed = [f"{root}/{name}" for name in entries(store) if name not in keep]
    if doomed:
        fs.rm(doomed, recursive=True)


def remove_partials(store: str) -> None:
    """Delete ``*.partial`` files half-written by a killed writer (the caller holds the store lock).

    Zarr's local store writes each file to a ``*.partial`` temporary and renames
    it; an object PUT is atomic, so only local folders hold such leftovers. (A
    chunk left unfinished on a backend that writes in place is harmless too:
    its ``done`` flag is written after it, so a resume rewrites it.)
    """
    if not is_local(store):
        return
    for partial in Path(store).rglob("*.partial"):
        partial.unlink()
