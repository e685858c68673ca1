"""fedtrack.atomic: the one atomic-write helper (temporary file in the same folder, fsync, rename; the
temporary removed on any error; the caller's error type preserved)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from fedtrack.atomic import atomic_file, write_atomic
from fedtrack.services.snapshot import read_sealed, write_sealed


class CallersError(Exception):
    """An error of the caller's own, raised half-way through a write."""


def test_a_file_is_replaced_whole_after_an_fsync_of_its_temporary_in_the_same_folder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    synced: list[str] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        real_fsync(fd)

    def replace(src: str | Path, dst: str | Path) -> None:
        assert [Path(p) for p in synced] == [Path(src)] and Path(src).parent == tmp_path  # fsync'ed, then renamed
        assert target.read_bytes() == b"old"  # nothing reached the target before the rename
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    write_atomic(target, b"new data")
    assert target.read_bytes() == b"new data" and len(synced) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]


def test_a_snapshot_is_written_whole_without_an_fsync(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    synced: list[int] = []
    monkeypatch.setattr(os, "fsync", synced.append)
    write_sealed(tmp_path / "s.snapshot", b"magic\n", b"state")
    assert synced == [] and read_sealed(tmp_path / "s.snapshot", b"magic\n") == b"state"
    write_atomic(tmp_path / "out.bin", b"data")
    assert len(synced) == 1  # the default: durable


def test_permissions_are_those_asked_less_the_umask(tmp_path: Path) -> None:
    write_atomic(tmp_path / "key.pem", b"secret", permissions=0o600)
    assert stat.S_IMODE((tmp_path / "key.pem").stat().st_mode) == 0o600
    old = os.umask(0o022)
    try:
        with atomic_file(tmp_path / "out.txt", "w") as fh:
            fh.write("text")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "out.txt").stat().st_mode) == 0o644
    assert (tmp_path / "out.txt").read_text() == "text"


@pytest.mark.parametrize("error", [CallersError("half-way"), KeyboardInterrupt(), OSError(28, "No space left")])
def test_an_error_in_the_block_leaves_the_target_as_it_was_and_no_temporary(tmp_path: Path,
                                                                           error: BaseException) -> None:
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    with pytest.raises(type(error)) as raised, atomic_file(target) as fh:
        fh.write(b"partial")
        raise error
    assert raised.value is error  # the caller's own error, not wrapped
    assert target.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["out.bin"]


def test_a_rename_that_fails_removes_the_temporary_and_raises_its_oserror(tmp_path: Path) -> None:
    (tmp_path / "dir").mkdir()  # the target is a folder: os.replace refuses
    with pytest.raises(IsADirectoryError):
        write_atomic(tmp_path / "dir", b"data")
    assert [p.name for p in tmp_path.iterdir()] == ["dir"] and not any((tmp_path / "dir").iterdir())


def test_a_folder_that_does_not_exist_is_an_oserror_and_creates_nothing(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        write_atomic(tmp_path / "gone" / "out.bin", b"data")
    assert list(tmp_path.iterdir()) == []


def test_a_stream_is_written_into_not_replaced(tmp_path: Path) -> None:
    """``replay --out /dev/stdout`` run as root replaced the link ``/dev/stdout`` (here: a FIFO, and a link to it)
    with a regular file holding the output, which no reader got; now a target that is a device or pipe is written
    into and stays what it was (tour61)."""
    import threading

    from fedtrack.jsonl import output_file

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    link = tmp_path / "stdout"
    link.symlink_to(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    with output_file(link) as fh:
        fh.write('{"t": 0.0}\n')
    reader.join(timeout=10)
    assert got == [b'{"t": 0.0}\n']
    assert stat.S_ISFIFO(fifo.stat().st_mode) and link.is_symlink() and os.readlink(link) == str(fifo)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe", "stdout"]


def test_a_symlink_is_written_through_to_its_target_and_stays_a_link(tmp_path: Path) -> None:
    """``--out latest.jsonl``, a link to a run's file in another folder: the run's file is replaced (its temporary
    beside it) and the link kept, a dangling one's target created; before tour62 the link became a regular file."""
    from fedtrack.jsonl import output_file

    runs = tmp_path / "runs"
    runs.mkdir()
    target = runs / "run5.jsonl"
    target.write_text("old\n")
    link, dangling = tmp_path / "latest.jsonl", tmp_path / "next.jsonl"
    link.symlink_to(Path("runs") / "run5.jsonl")
    dangling.symlink_to(runs / "run6.jsonl")
    with output_file(link) as fh:
        fh.write('{"t": 0.0}\n')
    write_atomic(dangling, b"new\n")
    assert target.read_text() == '{"t": 0.0}\n' and (runs / "run6.jsonl").read_bytes() == b"new\n"
    assert link.is_symlink() and os.readlink(link) == str(Path("runs") / "run5.jsonl")
    assert dangling.is_symlink() and os.readlink(dangling) == str(runs / "run6.jsonl")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["latest.jsonl", "next.jsonl", "runs"]
    assert sorted(p.name for p in runs.iterdir()) == ["run5.jsonl", "run6.jsonl"]
