"""Atomic writes: complete files or nothing, parents created, temp files cleaned up."""

from __future__ import annotations

import os
from pathlib import Path
import stat

import pytest

from rigcal import interrupts
from rigcal.errors import InputError
from rigcal.io import atomic
from rigcal.io.atomic import atomic_write_bytes, atomic_write_text, staged_folder


def test_text_creates_parents_and_returns_path(tmp_path):
    target = tmp_path / "a" / "b" / "out.txt"
    got = atomic_write_text(target, "héllo\nworld\n")
    assert got == target
    assert target.read_bytes() == "héllo\nworld\n".encode("utf-8")
    assert sorted(p.name for p in target.parent.iterdir()) == ["out.txt"]


def test_bytes_round_trip_and_overwrite(tmp_path):
    target = tmp_path / "data.bin"
    atomic_write_bytes(str(target), b"\x00\x01old")
    atomic_write_bytes(target, b"\xffnew")
    assert target.read_bytes() == b"\xffnew"
    assert [p.name for p in tmp_path.iterdir()] == ["data.bin"]


def test_overwrite_keeps_mode(tmp_path):
    target = tmp_path / "f.txt"
    target.write_text("old")
    os.chmod(target, 0o640)
    atomic_write_text(target, "new")
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    assert target.read_text() == "new"


def test_failed_replace_leaves_old_file_and_no_temp(tmp_path, monkeypatch):
    target = tmp_path / "f.txt"
    target.write_text("old")

    def boom(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic.os, "replace", boom)
    with pytest.raises(InputError, match=r"f\.txt: cannot write file: No space left"):
        atomic_write_text(target, "new")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["f.txt"]


def test_non_os_error_is_reraised_and_temp_removed(tmp_path, monkeypatch):
    def interrupted(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic.os, "fsync", interrupted)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_text(tmp_path / "f.txt", "new")
    assert list(tmp_path.iterdir()) == []


def test_target_is_directory(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(InputError, match=r"d: is a directory"):
        atomic_write_text(tmp_path / "d", "x")


def test_parent_is_a_file(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match=r"file: cannot create output directory"):
        atomic_write_text(tmp_path / "file" / "out.txt", "x")


def test_bytes_in_parts(tmp_path):
    import numpy as np

    arr = np.arange(5, dtype="<u2")
    path = atomic_write_bytes(tmp_path / "p.bin", [b"head", bytearray(b"-"), arr.data])
    assert path.read_bytes() == b"head-" + arr.tobytes()
    with pytest.raises(TypeError, match="must be bytes, got str"):
        atomic_write_bytes(tmp_path / "q.bin", [b"ok", "text"])  # type: ignore[list-item]
    assert not (tmp_path / "q.bin").exists()


def test_wrong_types():
    with pytest.raises(TypeError, match="must be str"):
        atomic_write_text("x", b"bytes")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="must be bytes"):
        atomic_write_bytes("x", "text")  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------
# staged_folder: a set of files written as one


def test_staged_folder_publishes_the_whole_set_at_once(tmp_path):
    from rigcal.io.atomic import OUTPUT_MARKER, staged_folder

    out = tmp_path / "out"
    with staged_folder(out) as stage:
        (stage / "a.yaml").write_text("a")
        assert not out.exists()  # nothing visible until the block ends
        (stage / "b.png").write_bytes(b"b")
    assert sorted(p.name for p in out.iterdir()) == sorted([OUTPUT_MARKER, "a.yaml", "b.png"])
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_staged_folder_leaves_the_old_set_on_error(tmp_path):
    from rigcal.io.atomic import staged_folder

    out = tmp_path / "out"
    with staged_folder(out) as stage:
        (stage / "a.yaml").write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with staged_folder(out) as stage:
            (stage / "a.yaml").write_text("new")
            raise KeyboardInterrupt
    assert (out / "a.yaml").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # the staging folder is gone


def test_staged_folder_replaces_an_earlier_output(tmp_path):
    from rigcal.io.atomic import staged_folder

    out = tmp_path / "out"
    with staged_folder(out) as stage:
        (stage / "old.yaml").write_text("old")
    with staged_folder(out) as stage:
        (stage / "new.yaml").write_text("new")
    assert not (out / "old.yaml").exists() and (out / "new.yaml").read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_staged_folder_refuses_a_folder_it_did_not_write(tmp_path):
    from rigcal.io.atomic import staged_folder

    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("user data")
    with pytest.raises(InputError, match="did not write"):
        with staged_folder(out):
            pass
    assert [p.name for p in out.iterdir()] == ["mine.txt"]
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        with staged_folder(tmp_path / "file"):
            pass


def test_staged_folder_accepts_an_empty_folder(tmp_path):
    from rigcal.io.atomic import staged_folder

    out = tmp_path / "out"
    out.mkdir()
    with staged_folder(out) as stage:
        (stage / "a").write_text("a")
    assert (out / "a").read_text() == "a"


def test_a_stage_is_synced_once_not_after_every_file(tmp_path, monkeypatch):
    """Files written into a staged folder skip the per-file directory sync; the stage is synced
    once before it is published, then its parent; a file written elsewhere still syncs its own
    folder."""
    import rigcal.io.atomic as atomic

    synced = []
    monkeypatch.setattr(atomic, "_fsync_directory", lambda d: synced.append(Path(d).name))
    with atomic.staged_folder(tmp_path / "out") as stage:
        for k in range(5):
            atomic.atomic_write_text(stage / f"f{k}.txt", "x")
        assert synced == []
    assert synced[0].startswith(".out.") and synced[0].endswith(".partial")
    assert synced[1:] == [tmp_path.name] and (tmp_path / "out" / "f4.txt").is_file()
    synced.clear()
    atomic.atomic_write_text(tmp_path / "alone.txt", "y")
    assert synced == [tmp_path.name]


@pytest.fixture
def interrupt():
    """Records an interrupt as the command line's signal handler does (forgotten afterwards)."""
    yield lambda: interrupts.request(KeyboardInterrupt)
    interrupts.clear()


def test_a_recorded_interrupt_stops_a_file_commit(tmp_path, interrupt):
    """An interrupt that some code swallowed still keeps the new file from replacing the old."""
    target = tmp_path / "a.yaml"
    atomic_write_text(target, "old")
    interrupt()
    with pytest.raises(KeyboardInterrupt):
        atomic_write_text(target, "new")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.yaml"]


def test_a_recorded_interrupt_stops_a_folder_commit(tmp_path, interrupt):
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        with staged_folder(out) as stage:
            (stage / "calibration.yaml").write_text("x")
            interrupt()
    assert not list(tmp_path.iterdir())


def test_without_an_interrupt_commits_go_ahead(tmp_path):
    assert interrupts.requested() is None
    with staged_folder(tmp_path / "out") as stage:
        atomic_write_text(stage / "a.txt", "a")
    assert (tmp_path / "out" / "a.txt").read_text() == "a"


def test_check_output_folder_refuses_before_any_work(tmp_path):
    from rigcal.io.atomic import check_output_folder, staged_folder

    assert check_output_folder(tmp_path / "new" / "out") == tmp_path / "new" / "out"
    (tmp_path / "file").write_text("mine")
    with pytest.raises(InputError, match=r"--out .*file: exists and is not a folder"):
        check_output_folder(tmp_path / "file")
    with pytest.raises(InputError, match=r"--out .*file/out: cannot use as output folder: Not a directory"):
        check_output_folder(tmp_path / "file" / "out")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.tex").write_text("x")
    with pytest.raises(InputError, match=r"holds files rigcal did not write \(thesis.tex\)"):
        check_output_folder(tmp_path / "mine")
    with pytest.raises(InputError, match=r"--out .*mine: holds an input of this run \(.*thesis.tex\)"):
        check_output_folder(tmp_path / "mine", inputs=(tmp_path / "mine" / "thesis.tex",))
    with staged_folder(tmp_path / "ours") as stage:
        (stage / "a.txt").write_text("a")
    assert check_output_folder(tmp_path / "ours") == tmp_path / "ours"  # an earlier rigcal output
    with pytest.raises(InputError, match=r"is an input of this run"):
        check_output_folder(tmp_path / "ours", inputs=(tmp_path / "ours",))
