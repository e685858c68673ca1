"""The one way fedtrack replaces a file whole (outputs, service snapshots, keys and certificates, the
launcher's start file): :func:`atomic_file` and :func:`write_atomic`.

The contract: the data go to a new temporary file in the target's own folder (``.NAME.PID.RANDOM.part``,
created exclusively with ``permissions`` less the umask), are flushed and fsync'ed, and the file is
renamed onto the target (``os.replace``, atomic within one file system). A reader therefore sees the old
file or the whole new one, never a part, and after a crash of the machine the renamed file holds its
data (the folder is not fsync'ed: a power cut may leave the old file in place, never a torn one).
``durable=False`` skips the fsync, for a file that only a restart of a process within the same boot
reads (the services' per-scan snapshots: the kernel's page cache outlives the process, and the fsync
cost 11.6 ms a write here against 0.5 ms, after every scan): still whole or absent to any reader, but
after a power cut it may be empty, which its reader refuses like any unusable snapshot. On
any exception (an OSError of the write, the fsync or the rename, the caller's own error raised in the
block, Ctrl-C) the temporary file is removed, the target is as it was, and the exception propagates
unchanged: each caller keeps its own error contract (:func:`fedtrack.jsonl.output_file` turns a full
disk into an InputError naming the file; a snapshot's writer counts the OSError).

A target that exists and is neither a regular file nor a folder (``/dev/null``, ``/dev/stdout`` on a pipe, a FIFO:
a stream, which no reader sees whole anyway) is written into, not renamed onto: before the tour61 session
``replay --out /dev/stdout`` run as root replaced the link ``/dev/stdout`` with a regular file of the pictures (and
``--out /dev/null`` would have replaced the device); as another user it failed, the folder ``/dev`` not writable.

A target that is a symbolic link is written through: the file it points to (followed to the end, created if missing)
is replaced as above, in that file's folder, and the link stays (``--out latest.jsonl``, a link to this run's file);
before the tour62 session the link itself was replaced by a regular file."""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any


def temporary_name(path: Path) -> Path:
    """A fresh temporary file's name beside ``path`` (hidden, unique to this process and call)."""
    return path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.part"


@contextlib.contextmanager
def atomic_file(path: str | Path, mode: str = "wb", permissions: int = 0o666,
                durable: bool = True) -> Iterator[IO[Any]]:
    """Replace ``path`` whole with what the block writes to the yielded file (``mode`` ``"w"``, text,
    or ``"wb"``), or leave it untouched if anything raises (the module's contract). OSError when the
    temporary file cannot be created (the folder missing or read-only)."""
    p = Path(path)
    if p.is_symlink():  # its target is replaced, the link kept (above)
        p = Path(os.path.realpath(p))
    if p.exists() and not p.is_file() and not p.is_dir():  # a device or pipe: a stream, written into (above)
        with open(p, mode) as stream:
            yield stream
        return
    tmp = temporary_name(p)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, permissions)
    try:
        with open(fd, mode) as fh:
            yield fh
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_atomic(path: str | Path, data: bytes, permissions: int = 0o666, durable: bool = True) -> None:
    """Replace ``path`` whole with ``data`` (:func:`atomic_file`)."""
    with atomic_file(path, "wb", permissions, durable) as fh:
        fh.write(data)
