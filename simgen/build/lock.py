"""A single-writer lock on a store: a second concurrent build is refused.

The lock is a small JSON object ``<store>/.lock`` naming its owner (host,
pid and a random token).

* Local folder (``file://`` URLs become folders): a file created atomically (``O_EXCL``).
* Object store or other fsspec URL: an object written through fsspec with
  ``mode="create"``. s3fs sends it as a conditional PUT (``If-None-Match: *``),
  atomic on AWS S3 and on the S3-compatible stores that honour it; other
  backends check for the object and then write it. The lock is then read back
  and refused unless it holds this build's token, which narrows a race between
  two builds started at the same instant to one round trip; it guards against
  starting a second build by mistake, not against an adversary.

A lock whose owner is on this host and no longer runs is taken over, so
resuming after a crash needs no manual step; so is one holding this process's
own pid (a restarted container reuses its pids), since a process never takes a
lock it already holds (a second :class:`StoreLock` on the same store in one
process is refused). A lock held by a live process or another host is refused;
:func:`unlock` (``simgen unlock STORE``) removes one left by a build that is gone.
"""

from __future__ import annotations

import json
import os
import socket
import uuid
from pathlib import Path

from shared.errors import InputError
from simgen.build.location import StoreURLError, filesystem, is_local, store_location

__all__ = ["LOCK_NAME", "StoreLocked", "StoreLock", "unlock"]

LOCK_NAME = ".lock"

# Stores locked by this process: a second lock on one of them is refused, not taken over.
_HELD: set[str] = set()


class StoreLocked(InputError):
    """Another build holds the store."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _lock_name(store: str) -> str:
    return str(Path(store) / LOCK_NAME) if is_local(store) else f"{store}/{LOCK_NAME}"


def _read(store: str) -> dict | None:
    """The lock's owner (``{}`` when unreadable), or ``None`` when there is no lock."""
    try:
        if is_local(store):
            raw = (Path(store) / LOCK_NAME).read_bytes()
        else:
            fs, root = filesystem(store)
            fs.invalidate_cache(root)
            raw = fs.cat_file(f"{root.rstrip('/')}/{LOCK_NAME}")
    except FileNotFoundError:
        return None
    try:
        holder = json.loads(raw)
    except ValueError:  # a writer killed between creating and filling the lock
        return {}
    return holder if isinstance(holder, dict) else {}


def _remove(store: str) -> None:
    if is_local(store):
        (Path(store) / LOCK_NAME).unlink(missing_ok=True)
        return
    fs, root = filesystem(store)
    try:
        fs.rm_file(f"{root.rstrip('/')}/{LOCK_NAME}")
    except FileNotFoundError:
        pass


class StoreLock:
    """Context manager holding ``<store>/.lock`` for the duration of a build (not re-entrant)."""

    def __init__(self, store: str | Path):
        self.store = store_location(store)
        self.path = _lock_name(self.store)
        self.owner = {"host": socket.gethostname(), "pid": os.getpid(), "token": uuid.uuid4().hex}

    def __enter__(self) -> StoreLock:
        if self.store in _HELD:
            raise StoreLocked(f"store {self.store} is locked by another build in this process (pid {os.getpid()})")
        for _ in range(2):
            try:
                self._create()
            except FileExistsError:
                self._break_if_stale()
                continue
            _HELD.add(self.store)
            return self
        raise StoreLocked(f"could not take the lock {self.path}")

    def _create(self) -> None:
        data = json.dumps(self.owner).encode()
        if is_local(self.store):
            path = Path(self.store) / LOCK_NAME
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            return
        fs, root = filesystem(self.store)
        try:
            fs.pipe_file(f"{root.rstrip('/')}/{LOCK_NAME}", data, mode="create")
        except FileExistsError:
            raise
        except Exception as exc:  # no bucket, no credentials, no permission, endpoint unreachable...
            raise StoreURLError(
                f"cannot write the lock {self.path}: {type(exc).__name__}: {exc} (the bucket or folder must exist, "
                "and this process and every worker need credentials that may write to it)"
            ) from exc
        holder = _read(self.store)
        if holder is None or holder.get("token") != self.owner["token"]:  # lost a race to another build
            raise StoreLocked(f"store {self.store} is locked by another build (host "
                              f"{(holder or {}).get('host')}, pid {(holder or {}).get('pid')}), just now")  # fmt: skip

    def _break_if_stale(self) -> None:
        holder = _read(self.store)
        if holder is None:  # released in the meantime
            return
        try:
            pid = int(holder.get("pid"))
        except (TypeError, ValueError):
            pid = 0  # unreadable owner: never taken over silently
        if holder.get("host") == self.owner["host"] and pid > 0 and (pid == os.getpid() or not _alive(pid)):
            _remove(self.store)  # left by a killed build on this host (or an earlier life of this container)
            return
        raise StoreLocked(
            f"store {self.store} is locked by another build (host {holder.get('host')}, pid {holder.get('pid')}); "
            f"wait for it to finish, or if that build is gone run `simgen unlock {self.store}` "
            f"(it deletes {self.path})"
        )

    def __exit__(self, *exc: object) -> None:
        _HELD.discard(self.store)
        holder = _read(self.store)
        if holder is not None and holder.get("token") == self.owner["token"]:
            _remove(self.store)  # never another build's lock (one that took over after `simgen unlock`)


def unlock(store: str | Path) -> dict | None:
    """Remove the lock of ``store`` left by a build that is gone; return its owner (``None``: no lock).

    Run it only when no build of ``store`` is running: a running build keeps
    writing, and a second build could then start beside it.
    """
    store = store_location(store)
    holder = _read(store)
    if holder is not None:
        _remove(store)
    return holder
