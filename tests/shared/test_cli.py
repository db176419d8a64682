"""The CLI helpers: which OSErrors are bad input, and checked id lists."""

from __future__ import annotations

import errno
import os

import pytest

from shared.cli import parse_ids, path_error
from shared.errors import InputError


@pytest.mark.parametrize(
    "exc, message",
    [
        (PermissionError(errno.EACCES, "Permission denied", "/ro/s.zarr"), "/ro/s.zarr: Permission denied"),
        (OSError(errno.EROFS, "Read-only file system", "/mnt/s.zarr"), "/mnt/s.zarr: Read-only file system"),
        (OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), "/given: No space left on device"),  # write(): no name
        (FileExistsError(errno.EEXIST, "File exists", "/a/file"), "/a/file: File exists (a file where a folder"),
        (NotADirectoryError(errno.ENOTDIR, "Not a directory", "/a/file/.lock"), "/a/file/.lock: Not a directory"),
        (IsADirectoryError(errno.EISDIR, "Is a directory", "/a/dir"), "(a folder where a file is expected)"),
    ],
)
def test_filesystem_refusals_become_input_errors_naming_the_path(exc, message):
    error = path_error(exc, "/given")
    assert isinstance(error, InputError) and message in str(error)


@pytest.mark.parametrize(
    "exc",
    [
        OSError("no errno"),
        OSError(errno.EBADF, "Bad file descriptor"),
        ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused"),
    ],
)
def test_other_os_errors_are_not_input_errors(exc):
    assert path_error(exc, "/given") is None


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "at least one"),
        ("1,x", "comma-separated integers"),
        ("3,-1", "[-1] must be >= 0"),
        ("4,2,4,2,5", "[2, 4] given more than once"),
    ],
)
def test_bad_id_lists_name_the_option(text, message):
    with pytest.raises(InputError, match="^--sites: ") as info:
        parse_ids(text, "--sites")
    assert message in str(info.value)


def test_id_list_keeps_the_order():
    assert parse_ids(" 7, 0,3 ,", "--sites") == [7, 0, 3]
