"""A single-writer lock on a store: a second concurrent build is refused.

The lock is a small JSON object ``<store>/.lock`` naming its owner: host, pid,
the process's start time and a random token. The start time (clock ticks
after boot, field 22 of ``/proc/<pid>/stat``; ``null`` where there is no
``/proc``) tells the owner from a later process given the same pid.

* Local folder (``file://`` URLs become folders): a file created atomically (``O_EXCL``).
* Object store or other fsspec URL: an object written through fsspec with
  ``mode="create"``. s3fs sends it as a conditional PUT (``If-None-Match: *``),
  atomic on AWS S3 and on the S3-compatible stores that honour it; other
  backends check for the object and then write it. The lock is then read back
  and refused unless it holds this build's token, which narrows a race between
  two builds started at the same instant to one round trip; it guards against
  starting a second build by mistake, not against an adversary.

A lock whose owner is gone is taken over, so resuming after a crash needs no
manual step. The owner is gone when it was a process of this host and no
process runs with its pid and start time (a lock without a start time, from an
older simgen, is judged by its pid alone), or when it holds this process's own
pid (a restarted container reuses its pids), since a process never takes a
lock it already holds (a second :class:`StoreLock` on the same store in one
process is refused). A lock held by a running process, by another host or
naming no owner is refused. :func:`unlock` (``simgen unlock STORE``) removes
the lock of a build that is gone; it refuses while the owner runs on this
host, and needs ``force`` (``--force``) for an owner this host cannot check.
"""

from __future__ import annotations

import json
import os
import socket
import uuid
from pathlib import Path
from typing import Literal

from shared.errors import InputError
from simgen.store.location import StoreURLError, filesystem, is_local, store_location

__all__ = ["LOCK_NAME", "StoreLocked", "StoreLock", "check_unlocked", "unlock"]

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


def _start_time(pid: int) -> int | None:
    """When process ``pid`` started (clock ticks after boot); ``None`` without ``/proc`` or such a process."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_bytes()
        # fields after "(comm)", which may hold spaces, start at field 3: the start time is field 22
        return int(stat[stat.rindex(b")") + 2 :].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def _running(pid: int, start: int | None) -> bool:
    """Whether process ``pid`` of this host runs and, where both start times are known, started at ``start``."""
    if not _alive(pid):
        return False
    now = _start_time(pid)
    return start is None or now is None or now == start  # no start time to compare: judged by the pid alone


def _pid(holder: dict) -> int:
    """The pid a lock names (0 when it names none)."""
    try:
        return int(holder.get("pid"))
    except (TypeError, ValueError):
        return 0


def _owner_state(store: str, holder: dict) -> Literal["running", "gone", "unknown"]:
    """Whether the owner of ``holder``, the lock of ``store``, runs; ``"unknown"`` for another host or no owner."""
    pid = _pid(holder)
    if holder.get("host") != socket.gethostname() or pid <= 0:
        return "unknown"
    if pid == os.getpid():  # this process (a build holds it only while in _HELD) or an earlier life of this container
        return "running" if store in _HELD else "gone"
    return "running" if _running(pid, holder.get("start")) else "gone"


def _describe(holder: dict) -> str:
    """``host H, pid P``: the owner a lock names."""
    return f"host {holder.get('host')}, pid {holder.get('pid')}"


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


def _locked(store: str, holder: dict) -> StoreLocked:
    """The refusal of a store whose lock ``holder`` is not known to be gone."""
    return StoreLocked(
        f"store {store} is locked by another build ({_describe(holder)}); "
        f"wait for it to finish, or if that build is gone run `simgen unlock {store}` "
        f"(it deletes {_lock_name(store)})"
    )


def check_unlocked(store: str | Path) -> None:
    """Refuse, as :class:`StoreLock` would, a store whose lock a build that is not gone holds; reads only."""
    store = store_location(store)
    holder = _read(store)
    if holder is not None and _owner_state(store, holder) != "gone":
        raise _locked(store, holder)


class StoreLock:
    """Context manager holding ``<store>/.lock`` for the duration of a build (not re-entrant)."""

    def __init__(self, store: str | Path):
        self.store = store_location(store)
        self.path = _lock_name(self.store)
        pid = os.getpid()
        self.owner = {"host": socket.gethostname(), "pid": pid, "start": _start_time(pid), "token": uuid.uuid4().hex}

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
            raise StoreLocked(f"store {self.store} is locked by another build ({_describe(holder or {})}), just now")

    def _break_if_stale(self) -> None:
        holder = _read(self.store)
        if holder is None:  # released in the meantime
            return
        if _owner_state(self.store, holder) == "gone":
            _remove(self.store)  # left by a killed build on this host (or an earlier life of this container)
            return
        raise _locked(self.store, holder)

    def __exit__(self, *exc: object) -> None:
        _HELD.discard(self.store)
        holder = _read(self.store)
        if holder is not None and holder.get("token") == self.owner["token"]:
            _remove(self.store)  # never another build's lock (one that took over after `simgen unlock`)


def unlock(store: str | Path, force: bool = False) -> dict | None:
    """Remove the lock of ``store`` left by a build that is gone; return its owner (``None``: no lock).

    Raises :class:`StoreLocked` while the owner runs on this host (a running
    build keeps writing, and a second build could then start beside it), and,
    unless ``force``, when this host cannot check the owner (another host, or
    a lock naming none).
    """
    store = store_location(store)
    holder = _read(store)
    if holder is None:
        return None
    state = _owner_state(store, holder)
    if state == "running":
        pid = _pid(holder)
        raise StoreLocked(
            f"store {store} is locked by a build that is still running (pid {pid} on this host): stop it with "
            f"Ctrl-C in its terminal or `kill -INT {pid}`, and it removes its lock as it exits"
        )
    if state == "unknown" and not force:
        raise StoreLocked(
            f"store {store} is locked by a build this host cannot check ({_describe(holder)}); "
            f"make sure it is no longer running, then run `simgen unlock --force {store}`"
        )
    _remove(store)
    return holder
