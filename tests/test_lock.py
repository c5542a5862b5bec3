"""One campaign per folder: two ``experiment`` runs into
one ``--out`` used to both run every trial and store each twice."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap

import pytest

from jaxrecog._lock import LOCK_NAME, FolderLockedError, folder_lock

_HOLDER = textwrap.dedent("""
    import sys, time
    from jaxrecog._lock import folder_lock
    with folder_lock(*sys.argv[1:]):
        print("held", flush=True)
        time.sleep(120)
""")


@pytest.fixture
def holder():
    """A live process holding the lock on the folders given."""
    procs = []

    def start(*folders):
        p = subprocess.Popen([sys.executable, "-c", _HOLDER, *map(str, folders)], stdout=subprocess.PIPE, text=True)
        procs.append(p)
        assert p.stdout.readline().strip() == "held"
        return p

    yield start
    for p in procs:
        p.kill()
        p.wait(timeout=30)
        p.stdout.close()


def test_a_second_run_is_refused_with_the_pid_of_the_first(tmp_path, holder, monkeypatch, capsys):
    from jaxrecog import cli
    from jaxrecog import campaigns as ex

    out = tmp_path / "out"
    first = holder(out, out / "work")

    def no_run(*a, **k):
        raise AssertionError("the second run started its campaign")

    monkeypatch.setattr(ex, "run_case", no_run)
    assert cli.main(["experiment", "i", "--out", str(out), "--quick"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and re.fullmatch(
        rf"jaxrecog: error: {re.escape(str(out))} is in use by another jaxrecog experiment run \(PID {first.pid} "
        r"on \S+, started \d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC\); wait for it to end or choose another folder", err[0]), err
    # the same work folder under another --out is refused too
    assert cli.main(["experiment", "i", "--out", str(tmp_path / "other"), "--workdir", str(out / "work"),
                     "--quick"]) == 1
    assert f"{out / 'work'} is in use by another jaxrecog experiment run (PID {first.pid}" in capsys.readouterr().err


def test_the_lock_of_a_killed_run_is_taken_over_and_a_finished_run_leaves_no_file(tmp_path, holder):
    dead = holder(tmp_path)
    with pytest.raises(FolderLockedError, match=f"PID {dead.pid} "):
        with folder_lock(tmp_path):
            pass
    dead.send_signal(signal.SIGKILL)
    dead.wait(timeout=30)
    assert str(dead.pid) in (tmp_path / LOCK_NAME).read_text()   # its file is still there, naming a dead PID
    with folder_lock(tmp_path):
        assert (tmp_path / LOCK_NAME).read_text().split()[0] == str(os.getpid())
    assert not (tmp_path / LOCK_NAME).exists()


def test_a_refused_run_holds_nothing_and_one_folder_twice_is_locked_once(tmp_path, holder):
    a, b = tmp_path / "a", tmp_path / "b"
    holder(b)
    with pytest.raises(FolderLockedError):
        with folder_lock(a, b):
            pass
    with folder_lock(a, a / "." ):   # a was released when b was refused; the same folder twice is one lock
        pass
    assert not (a / LOCK_NAME).exists()
    # a link to the lock file is not followed
    (tmp_path / "c").mkdir()
    victim = tmp_path / "victim"
    victim.write_text("precious")
    (tmp_path / "c" / LOCK_NAME).symlink_to(victim)
    with pytest.raises(OSError):
        with folder_lock(tmp_path / "c"):
            pass
    assert victim.read_text() == "precious"
