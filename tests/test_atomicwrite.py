"""survey.atomicwrite: the one atomic writer (umask modes, no leftovers) and the output checks."""
from __future__ import annotations

import os
import stat

import pytest

from survey.atomicwrite import (MARKER_NAME, OutputError, atomic_path, check_outputs, guard_overwrite,
                                write_marker, write_text_atomic)


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    yield
    os.umask(old)


def _mode(p) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


def test_new_file_gets_the_umask_mode_not_0600(tmp_path, umask_027):
    p = write_text_atomic(tmp_path / "a.csv", "x\n")
    assert _mode(p) == 0o640
    os.umask(0o022)
    p = write_text_atomic(tmp_path / "b.csv", "x\n")
    assert _mode(p) == 0o644
    plain = tmp_path / "plain.csv"
    plain.write_text("x\n")
    assert _mode(p) == _mode(plain)


def test_failure_leaves_the_old_file_and_no_temporary(tmp_path):
    p = tmp_path / "out.xlsx"
    p.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(p) as tmp:
            tmp.write_text("half")
            raise RuntimeError("disk full")
    assert p.read_text() == "old"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["out.xlsx"]


def test_temporary_keeps_the_extension(tmp_path):
    with atomic_path(tmp_path / "plot.png") as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path and tmp.name.startswith(".")
        tmp.write_bytes(b"x")


def test_check_outputs_refuses_inputs_raw_files_folders_duplicates(tmp_path):
    src = tmp_path / "track.csv"
    src.write_text("x")
    (tmp_path / "imu.csv").write_text("x")
    with pytest.raises(OutputError, match="--csv .*track.csv.*inputs"):
        check_outputs([("--csv", src)], inputs=[src])
    with pytest.raises(OutputError, match="imu.csv"):
        check_outputs([("--csv", tmp_path / "imu.csv")])
    with pytest.raises(OutputError, match="is a folder"):
        check_outputs([("--xlsx", tmp_path)])
    with pytest.raises(OutputError, match="does not exist"):
        check_outputs([("--xlsx", tmp_path / "no" / "a.xlsx")])
    with pytest.raises(OutputError, match="also given to --csv"):
        check_outputs([("--csv", tmp_path / "a.csv"), ("--xlsx", tmp_path / "a.csv")])
    check_outputs([("--csv", tmp_path / "new.csv"), ("--xlsx", None)], inputs=[src])


def test_guard_overwrite_only_replaces_own_marked_folders(tmp_path):
    out = tmp_path / "run"
    guard_overwrite(out, "simulate", force=False)  # absent: fine
    out.mkdir()
    (out / "imu.csv").write_text("raw")
    with pytest.raises(OutputError, match="--force"):
        guard_overwrite(out, "simulate", force=False)
    with pytest.raises(OutputError, match=MARKER_NAME):
        guard_overwrite(out, "simulate", force=True)
    write_marker(out, "simulate")
    guard_overwrite(out, "simulate", force=True)
    with pytest.raises(OutputError):
        guard_overwrite(out, "tgms simulate", force=True)
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(OutputError, match="not a folder"):
        guard_overwrite(f, "simulate", force=True)


def test_a_write_error_names_the_users_file_not_the_temporary(tmp_path):
    import errno

    target = tmp_path / "sheet.xlsx"
    with pytest.raises(OSError) as info:
        with atomic_path(target) as tmp:
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert info.value.filename == str(target) and info.value.errno == errno.ENOSPC
    assert list(tmp_path.iterdir()) == []


def test_all_or_nothing_writes_every_output_or_none(tmp_path):
    from survey.atomicwrite import all_or_nothing

    a, b = tmp_path / "a.csv", tmp_path / "b.png"
    a.write_text("old a")
    with pytest.raises(RuntimeError):
        with all_or_nothing():
            write_text_atomic(a, "new a")
            assert a.read_text() == "old a"  # not yet in place
            raise RuntimeError("the plots failed")
    assert a.read_text() == "old a" and not b.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv"]
    with all_or_nothing():
        write_text_atomic(a, "new a")
        write_text_atomic(b, "new b")
    assert a.read_text() == "new a" and b.read_text() == "new b"


def test_claim_folder_gives_a_new_folder_to_one_of_two_at_once(tmp_path):
    # (bug hunt 2026-11-26) two sessions started together into one new --out both passed the guard
    # and wrote over each other's results: the claim is exclusive
    import threading

    from survey.atomicwrite import OutputError, claim_folder, made_by

    claim_folder(tmp_path / "a", "survey session s1")
    claim_folder(tmp_path / "a", "survey session s1")          # its own again: fine
    with pytest.raises(OutputError, match="was just taken by another command"):
        claim_folder(tmp_path / "a", "survey session s2")
    for trial in range(20):
        folder, won, barrier = tmp_path / f"race{trial}", [], threading.Barrier(2)

        def claim(name):
            barrier.wait()
            try:
                claim_folder(folder, name)
                won.append(name)
            except OutputError:
                pass

        threads = [threading.Thread(target=claim, args=(f"survey session s{k}",)) for k in (1, 2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(won) == 1 and made_by(folder, won[0])
