"""What a SIGKILL leaves behind: pool workers and temporary files (issue 35, item 13)."""

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from pose.fileio import _writer, atomic_write, remove_orphaned_tmp

POOL_THEN_WAIT = textwrap.dedent(
    """
    import os, sys, time
    from scorbot_gym.experiments.workers import worker_pool

    if __name__ == "__main__":
        pool = worker_pool(2)
        for _ in range(3):
            pool.submit(time.sleep, 300)  # busy workers, as in a sweep
        while len(pool._processes) < 2:  # both started (spawned on demand)
            time.sleep(0.05)
        print("ready", flush=True)
        time.sleep(300)
    """
)


def _running(pid: int) -> bool:
    """Alive and not a zombie (a re-parented worker may wait to be reaped)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def _children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (the pool's workers and its resource tracker)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_pool_workers_die_when_their_parent_is_killed():
    parent = subprocess.Popen(
        [sys.executable, "-c", POOL_THEN_WAIT], stdout=subprocess.PIPE, text=True
    )
    try:
        assert parent.stdout.readline().strip() == "ready"
        workers = _children(parent.pid)
        assert len(workers) >= 2 and all(_running(p) for p in workers)
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
    deadline = time.monotonic() + 30  # a deadline for the check, not a speed requirement
    while any(_running(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [p for p in workers if _running(p)]
    for p in left:  # don't leave them to the next test
        os.kill(p, signal.SIGKILL)
    assert left == []


KILLED_WRITE = textwrap.dedent(
    """
    import sys, time
    from pose.fileio import atomic_write

    def write(f):
        f.write(b"half a file")
        f.flush()
        print("writing", flush=True)
        time.sleep(300)

    atomic_write(sys.argv[1], write)
    """
)


def test_a_killed_writes_tmp_file_is_removed_by_the_next_run(tmp_path):
    target = tmp_path / "entry.npz"
    writer = subprocess.Popen(
        [sys.executable, "-c", KILLED_WRITE, str(target)], stdout=subprocess.PIPE, text=True
    )
    assert writer.stdout.readline().strip() == "writing"
    writer.send_signal(signal.SIGKILL)
    writer.wait()
    (orphan,) = tmp_path.glob(".entry.npz.*.tmp")
    assert f"-{writer.pid}." in orphan.name and not target.exists()

    live = tmp_path / f".other.npz.{_writer()}.abcd1234.tmp"  # this process: a write in progress
    live.write_bytes(b"")
    foreign = tmp_path / f".x.npz.elsewhere-{_dead_pid()}.abcd1234.tmp"  # another host's
    foreign.write_bytes(b"")
    assert remove_orphaned_tmp(tmp_path) == 1  # fresh, but its writer is dead
    assert not orphan.exists() and live.exists() and foreign.exists()
    old = time.time() - 3600
    os.utime(foreign, (old, old))
    assert remove_orphaned_tmp(tmp_path) == 1  # another host's goes by age only
    assert not foreign.exists() and live.exists()
    atomic_write(target, lambda f: f.write(b"whole"))
    assert target.read_bytes() == b"whole"


def test_a_checkpoint_write_removes_a_dead_writers_tmp_checkpoint(tmp_path):
    from scorbot_gym.rl.callbacks import atomic_save

    orphan = tmp_path / f".model.tmp{_dead_pid()}.zip"  # a run killed while saving
    orphan.write_bytes(b"PK")
    atomic_save(tmp_path / "model.zip", lambda p: Path(p).write_bytes(b"model"))
    assert (tmp_path / "model.zip").read_bytes() == b"model"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]
