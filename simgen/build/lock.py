"""A single-writer lock on a store: a second concurrent build is refused.

The lock is a file created atomically (``O_EXCL``) inside the store folder,
holding the owner's host and pid. A lock left by a killed build on this host
(its pid no longer runs) is taken over, so resuming after a crash needs no
manual step; a lock held by a live process or another host is refused.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

from shared.errors import InputError

__all__ = ["StoreLocked", "StoreLock"]

LOCK_NAME = ".lock"


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


class StoreLock:
    """Context manager holding ``<store>/.lock`` for the duration of a build."""

    def __init__(self, store: str | Path):
        self.path = Path(store) / LOCK_NAME
        self.owner = {"host": socket.gethostname(), "pid": os.getpid()}

    def __enter__(self) -> StoreLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                self._break_if_stale()
                continue
            with os.fdopen(fd, "w") as f:
                json.dump(self.owner, f)
            return self
        raise StoreLocked(f"could not take the lock {self.path}")

    def _break_if_stale(self) -> None:
        try:
            holder = json.loads(self.path.read_text())
        except (OSError, ValueError):
            holder = {}
        if holder.get("host") == self.owner["host"] and not _alive(int(holder.get("pid", -1))):
            self.path.unlink(missing_ok=True)  # left by a killed build on this host
            return
        raise StoreLocked(
            f"store {self.path.parent} is locked by another build (host {holder.get('host')}, pid "
            f"{holder.get('pid')}); wait for it to finish, or delete {self.path} if that build is gone"
        )

    def __exit__(self, *exc: object) -> None:
        self.path.unlink(missing_ok=True)
