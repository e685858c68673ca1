"""A service's state file for its restarts within a run (the fusion centre's state, the picture
merger's last merged time): written whole, a temporary file renamed into place (a kill leaves the
previous one), behind a BLAKE2b digest of its data that is checked before anything reads the data,
so a file cut or corrupted on disk is refused, never half-read."""

from __future__ import annotations

from hashlib import blake2b
from pathlib import Path

from fedtrack.atomic import write_atomic

DIGEST_BYTES = 32


def write_sealed(path: Path, magic: bytes, data: bytes) -> None:
    """Write ``magic``, the digest of ``data`` and ``data`` to ``path``, atomically
    (:func:`fedtrack.atomic.write_atomic`); on an OSError (the disk full, the file size limit, no file
    descriptor left), raised as it came, ``path`` is as it was and no temporary file is left."""
    write_atomic(path, magic + blake2b(data, digest_size=DIGEST_BYTES).digest() + data)


def unsealed(raw: bytes, magic: bytes) -> bytes:
    """The data of a file's bytes ``raw`` written by :func:`write_sealed` with ``magic``; ValueError
    when it is not one or its digest does not match (a corrupted or cut file)."""
    head = len(magic) + DIGEST_BYTES
    if not raw.startswith(magic) or len(raw) < head:
        raise ValueError(f"not a {magic.decode(errors='replace').strip()} file")
    data = raw[head:]
    if blake2b(data, digest_size=DIGEST_BYTES).digest() != raw[len(magic):head]:
        raise ValueError("checksum mismatch (a corrupted or cut file)")
    return data
