"""No work or data lost (issue 50, item 2): every output is checked before the work starts,
``train --out`` takes only a new/empty folder or its own run and locks it, and a killed
``demos`` leaves nothing behind that blocks a rerun.

Every refusal goes through the real command line: exit code 2, one line on stderr, no
traceback, nothing written, and (by a stand-in for the work that fails the test if called)
no episode, fit or training started.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from scorbot_gym.cli import main
from scorbot_gym.outputs import (
    OutputError,
    check_dataset_id,
    check_output_file,
    check_output_folder,
    exclusive_lock,
    parse_dataset_id,
)
from scorbot_gym.rl import runs

REPO = Path(__file__).resolve().parents[1]
TINY_TRAIN = [
    "--objects", "box", "--timesteps", "400", "--learning-starts", "50", "--eval-every", "400",
    "--eval-episodes", "1", "--checkpoint-every", "400", "--no-progress", "--no-tensorboard",
    "--hyperparams", "batch_size=16", "buffer_size=500", "net_arch=[8]",
]  # fmt: skip


def refused(argv: list[str], capsys) -> str:
    """Run the command; it must exit 2 with one line on stderr and no traceback (argparse's
    own refusals, while parsing, put the usage above their line)."""
    try:
        code = main(argv)
        usage = False
    except SystemExit as exc:
        code, usage = exc.code, True
    err = capsys.readouterr().err
    assert code == 2, (code, err)
    lines = err.strip().splitlines()
    assert "Traceback" not in err and (len(lines) == 1 or usage and lines[0].startswith("usage:"))
    return lines[-1]


def tree(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones too) with the hash of its bytes."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def unwritable_system_folder() -> Path:
    """A folder no one, root included, can create files in (``/sys``), or skip."""
    try:
        check_output_folder("/sys")
    except OutputError:
        return Path("/sys")
    pytest.skip("/sys accepts new files here")


@pytest.fixture()
def a_file(tmp_path) -> Path:
    path = tmp_path / "a_file"
    path.write_text("a user's file\n")
    return path


@pytest.fixture()
def no_work(monkeypatch):
    """Stand-ins for every kind of work the commands start: called, they fail the test."""
    import scorbot_gym.evaluation.compare as compare
    import scorbot_gym.evaluation.rollout as rollout
    import scorbot_gym.perception.training as perception
    import scorbot_gym.rl.datasets as datasets
    import scorbot_gym.rl.training as training

    def started(what):
        def fail(*args, **kwargs):
            raise AssertionError(f"{what} started although an output was bad")

        return fail

    monkeypatch.setattr(rollout, "run_rollout", started("a rollout"))
    monkeypatch.setattr(rollout, "run_rollouts", started("a rollout"))
    monkeypatch.setattr(compare, "compare", started("a comparison"))
    monkeypatch.setattr(perception, "train_models", started("a pose-model fit"))
    monkeypatch.setattr(datasets, "collect_episodes", started("an episode"))
    monkeypatch.setattr(training, "make_vec_env", started("training"))


# --- train --out ----------------------------------------------------------------------------


def test_train_refuses_a_folder_of_something_else_and_leaves_it_untouched(
    tmp_path, capsys, no_work
):
    """The folder of another tool, with a config.json and the names a run writes: refused,
    every file kept byte for byte, nothing added (no marker, no lock file)."""
    other = tmp_path / "experiment"
    for name in ("policy", "best", "tb", "monitor", "checkpoint"):
        (other / name).mkdir(parents=True)
        (other / name / "notes.txt").write_text(f"my {name} notes\n")
    (other / "config.json").write_text(json.dumps({"lr": 0.1, "tool": "something else"}))
    before = tree(other)
    err = refused(["train", "--out", str(other), *TINY_TRAIN], capsys)
    assert "is not empty and not a scorbot-gym run (best, checkpoint, config.json, " in err
    assert "nothing in it is touched" in err
    assert tree(other) == before and sorted(os.listdir(other)) == sorted(
        ["best", "checkpoint", "config.json", "monitor", "policy", "tb"]
    )
    # a single unrelated file is enough; so is a folder of several seeds' names
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "thesis.tex").write_text("\\documentclass{article}")
    assert "(thesis.tex)" in refused(["train", "--out", str(tmp_path / "docs")], capsys)
    assert "(thesis.tex)" in refused(
        ["train", "--out", str(tmp_path / "docs"), "--seeds", "0,1"], capsys
    )
    assert os.listdir(tmp_path / "docs") == ["thesis.tex"]


def test_train_refuses_out_paths_that_cannot_be_a_new_folder(tmp_path, a_file, capsys, no_work):
    cwd_before = sorted(os.listdir())
    assert "--out: an empty path is not a folder name" in refused(["train", "--out", ""], capsys)
    assert sorted(os.listdir()) == cwd_before
    err = refused(["train", "--out", str(a_file / "sub")], capsys)
    assert f"{a_file} is a file, so nothing can be created under it" in err
    assert f"--out {a_file} is a file, not a folder" in refused(
        ["train", "--out", str(a_file)], capsys
    )
    system = unwritable_system_folder()
    assert f"cannot write into {system}" in refused(["train", "--out", str(system / "x")], capsys)
    assert "no run folder at" in refused(["train", "--resume", ""], capsys)
    assert a_file.read_text() == "a user's file\n"


def test_python_train_refuses_the_same_folders(tmp_path, a_file):
    from scorbot_gym.rl.training import TrainConfig, train

    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text("{}")
    for out, message in ((other, "not a scorbot-gym run"), (a_file / "x", "is a file")):
        with pytest.raises(OutputError, match=message):
            train(TrainConfig(objects=["box"], timesteps=10), out)
    assert os.listdir(other) == ["config.json"]


def _wait_for(path: Path, proc: subprocess.Popen, timeout_s: float = 180.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        if proc.poll() is not None:
            raise AssertionError(f"the first train exited ({proc.returncode}): {proc.stderr}")
        if time.monotonic() > deadline:
            raise AssertionError(f"{path} did not appear within {timeout_s} s")
        time.sleep(0.2)


@pytest.mark.slow
def test_a_second_train_of_the_same_folder_is_refused_while_the_first_runs(tmp_path, capsys):
    """Two real processes: the first ``scorbot-gym train`` holds its folder's lock from the
    moment it writes its marker; a second ``--out`` or ``--resume`` of the folder is refused
    in one line naming the first's pid. Killed, the first takes its lock with it."""
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO), "MUJOCO_GL": "egl"}
    cmd = [sys.executable, "-m", "scorbot_gym.cli", "train", "--out", str(out), *TINY_TRAIN]
    first = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for(out / runs.MARKER, first)
        err = refused(["train", "--out", str(out), *TINY_TRAIN], capsys)
        assert f"run folder {out} is in use by another process (pid {first.pid})" in err
        if not (out / runs.CONFIG).is_file():  # --resume needs a run: the first's config.json
            (out / runs.CONFIG).write_text("{}")
        err = refused(["train", "--resume", str(out)], capsys)
        assert f"run folder {out} is in use by another process (pid {first.pid})" in err
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait()
    with exclusive_lock(out / runs.LOCK, "the killed run's folder"):
        pass


def test_train_out_restarts_its_own_stopped_run_and_deletes_only_what_it_wrote(tmp_path):
    """A run of this tool (its marker) that stopped before its first checkpoint: its files
    go, a file the user put beside them stays; with a checkpoint it must be resumed."""
    out = tmp_path / "run"
    (out / runs.TENSORBOARD).mkdir(parents=True)
    (out / runs.MONITOR).mkdir()
    (out / runs.CONFIG).write_text("{}")
    (out / runs.MARKER).write_text("{}")
    (out / "my_notes.txt").write_text("keep me")
    with runs.claim(out, new=True):
        assert sorted(os.listdir(out)) == sorted([runs.LOCK, runs.MARKER, "my_notes.txt"])
    (out / runs.CHECKPOINT).mkdir()
    (out / runs.CHECKPOINT / runs.STATE).write_text("{}")
    with pytest.raises(OutputError, match=f"already holds a run; resume it with --resume {out}"):
        runs.check_new_run_folder(out)


def test_the_lock_is_exclusive_across_processes(tmp_path):
    """:func:`exclusive_lock` held by another process refuses; released, it is free again."""
    lock = tmp_path / "x.lock"
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import sys, time
            from scorbot_gym.outputs import exclusive_lock
            with exclusive_lock({str(lock)!r}, "x"):
                print("held", flush=True)
                sys.stdin.readline()
        """)],
        env={**os.environ, "PYTHONPATH": str(REPO)},
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(
            OutputError, match=rf"^x is in use by another process \(pid {holder.pid}\)"
        ):
            with exclusive_lock(lock, "x"):
                pass
    finally:
        holder.communicate("\n")
    with exclusive_lock(lock, "x"):
        pass


# --- demos ----------------------------------------------------------------------------------


@pytest.fixture()
def minari_root(tmp_path, monkeypatch) -> Path:
    root = tmp_path / "datasets"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return root


@pytest.mark.parametrize(
    "dataset_id",
    ["", "scorbot/grasp", "../../x/y-v0", "scorbot/grasp oracle-v0", "/tmp/x/y-v0", "a//b-v0",
     "a/b-v0", "scorbot/grasp-v01"],
)  # fmt: skip
def test_demos_refuses_a_bad_dataset_id_before_any_episode(
    dataset_id, minari_root, capsys, no_work
):
    err = refused(["demos", "--episodes", "2", "--out", dataset_id], capsys)
    assert f"dataset {dataset_id!r} is not a Minari dataset id [namespace/]name-vN" in err
    assert not minari_root.exists() or not any(minari_root.rglob("*-v*"))


def test_demos_refuses_an_unwritable_datasets_folder_before_any_episode(
    tmp_path, a_file, monkeypatch, capsys, no_work
):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(a_file / "datasets"))
    err = refused(["demos", "--episodes", "2", "--out", "scorbot/grasp-v0"], capsys)
    assert f"the datasets folder {a_file / 'datasets'}: {a_file} is a file" in err
    system = unwritable_system_folder()
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(system / "datasets"))
    err = refused(["demos", "--episodes", "2", "--out", "scorbot/grasp-v0"], capsys)
    assert f"cannot write into {system}" in err


KILLED_MID_WRITE = """
import os, signal
from minari.dataset._storages.hdf5_storage import HDF5Storage

write = HDF5Storage.update_episodes

def write_one_then_die(self, episodes):
    write(self, list(episodes)[:1])  # the first episode is on disk, the second never comes
    os.kill(os.getpid(), signal.SIGKILL)

HDF5Storage.update_episodes = write_one_then_die
from scorbot_gym.cli import main
main(["demos", "--episodes", "2", "--seed", "3", "--out", "scorbot/killed-v0"])
"""


@pytest.mark.slow
def test_a_demos_killed_mid_write_leaves_nothing_that_blocks_a_rerun(minari_root, capsys):
    """SIGKILL while Minari writes the dataset: no dataset appears (Minari lists none, the
    id's folder does not exist), the rerun of the same command succeeds and clears the killed
    run's staging folder; a third run of the id is refused and leaves the dataset whole."""
    import minari

    env = {**os.environ, "PYTHONPATH": str(REPO), "MUJOCO_GL": "egl"}
    killed = subprocess.run(
        [sys.executable, "-c", KILLED_MID_WRITE], env=env, capture_output=True, text=True
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    staged = [p for p in minari_root.iterdir() if p.name.startswith(".scorbot-gym-staging.")]
    assert len(staged) == 1 and any(staged[0].rglob("*.hdf5")), "killed while writing"
    assert not (minari_root / "scorbot" / "killed-v0").exists()
    assert "scorbot/killed-v0" not in minari.list_local_datasets()

    argv = ["demos", "--episodes", "2", "--seed", "3", "--out", "scorbot/killed-v0"]
    assert main(argv) == 0
    assert "dataset scorbot/killed-v0: 2 episodes" in capsys.readouterr().out
    assert not staged[0].exists()
    assert minari.load_dataset("scorbot/killed-v0").total_episodes == 2
    before = tree(minari_root / "scorbot" / "killed-v0")

    err = refused([*argv[:-1], "scorbot/killed-v0"], capsys)
    assert "a Minari dataset of that id exists already" in err
    assert tree(minari_root / "scorbot" / "killed-v0") == before
    assert list(minari.list_local_datasets()) == ["scorbot/killed-v0"]


def test_demos_refuses_a_taken_id_before_any_episode(minari_root, capsys, no_work):
    """Any folder at the id (a user's dataset, complete or not) is left alone."""
    taken = minari_root / "scorbot" / "mine-v0" / "data"
    taken.mkdir(parents=True)
    (taken / "main_data.hdf5").write_bytes(b"a user's data")
    err = refused(["demos", "--episodes", "1", "--out", "scorbot/mine-v0"], capsys)
    assert "'scorbot/mine-v0': a Minari dataset of that id exists already" in err
    assert (taken / "main_data.hdf5").read_bytes() == b"a user's data"


def test_dataset_ids_we_accept_are_ids_minari_parses_alike():
    from minari.dataset.minari_dataset import parse_dataset_id as minari_parse

    for dataset_id in ("x-v0", "scorbot/grasp-oracle-v0", "ab/cd/e_f-v12", "a-b/c-v1-v3"):
        assert parse_dataset_id(dataset_id) == minari_parse(dataset_id)
    for dataset_id in ("x", "x-v", "a/x-v0", "ns/x y-v0", "ns/-v0", "ns/x-v007", "ns//x-v0"):
        with pytest.raises(OutputError, match="is not a Minari dataset id"):
            parse_dataset_id(dataset_id)


# --- rollout, compare, pose train: bad outputs before any episode or fit ----------------------


@pytest.mark.parametrize(
    ("command", "option", "name", "fragment"),
    [
        (["rollout"], "--json", "under_a_file", "is a file, so nothing can be created under it"),
        (["rollout"], "--json", "folder", "is a folder; give a file name"),
        (["rollout"], "--json", "summary.txt", "the name must end in .json or .json.gz"),
        (["rollout"], "--json", "system", "cannot write into /sys"),
        (["rollout"], "--video", "under_a_file", "is a file, so nothing can be created under it"),
        (["rollout"], "--video", "system", "cannot write into /sys"),
        (["compare", "--policies", "scripted"], "--png", "under_a_file", "is a file, so nothing"),
        (["compare", "--policies", "scripted"], "--png", "system", "cannot write into /sys"),
        (["compare", "--policies", "scripted"], "--json", "under_a_file", "is a file, so nothing"),
        (["compare", "--policies", "scripted"], "--json", "folder", "is a folder; give a file"),
        (["pose", "train", "--objects", "box"], "--out", "under_a_file", "is a file, so nothing"),
        (["pose", "train", "--objects", "box"], "--out", "system", "cannot write into /sys"),
        (["pose", "train", "--objects", "box"], "--out", "folder", "is a folder; give a file"),
        (["pose", "train", "--objects", "box"], "--out", "models.pkl", "must end in .npz"),
        (["pose", "train", "--objects", "box"], "--out", "empty", "an empty path is not a file"),
    ],
)
def test_bad_outputs_are_refused_before_any_episode_or_fit(
    command, option, name, fragment, tmp_path, a_file, capsys, no_work
):
    suffix = {"--json": ".json", "--png": ".png", "--video": ".gif", "--out": ".npz"}[option]
    if name == "system":
        path = str(unwritable_system_folder() / f"x{suffix}")
    else:
        path = {
            "under_a_file": str(a_file / f"x{suffix}"),
            "folder": str(tmp_path),
            "empty": "",
        }.get(name, str(tmp_path / name))
    before = sorted(os.listdir(tmp_path))
    err = refused([*command, option, path], capsys)
    assert err.startswith(f"scorbot-gym {' '.join(command[: 2 if command[0] == 'pose' else 1])}")
    assert f"error: {option}" in err and fragment in err, err
    assert sorted(os.listdir(tmp_path)) == before and a_file.read_text() == "a user's file\n"


def test_record_episodes_checks_its_video_path_before_the_first_episode(a_file):
    """The Python entry point behind ``rollout --video``: the env is never touched."""
    from scorbot_gym.evaluation.video import record_episodes

    with pytest.raises(OutputError, match="is a file, so nothing can be created under it"):
        record_episodes(object(), object(), [0], a_file / "v.mp4")
    with pytest.raises(OutputError, match="must end in .mp4 or .gif"):
        record_episodes(object(), object(), [0], a_file.parent / "v.avi")


# --- the checks themselves ------------------------------------------------------------------


def test_output_checks_create_nothing_and_accept_new_nested_paths(tmp_path):
    new = tmp_path / "a" / "b"
    assert check_output_file(new / "r.json", "--json", (".json",)) == new / "r.json"
    assert check_output_folder(new / "run", "--out") == new / "run"
    (tmp_path / "old.json").write_text("{}")  # an existing file is replaced atomically
    check_output_file(tmp_path / "old.json", "--json", (".json",))
    assert os.listdir(tmp_path) == ["old.json"]
    with pytest.raises(OutputError, match="NUL"):
        check_output_file("a\0b.json", "--json")
    with pytest.raises(OutputError, match="File name too long"):
        check_output_folder(tmp_path / ("x" * 300), "--out")


def test_check_dataset_id_names_the_folder_it_will_take(minari_root):
    assert check_dataset_id("scorbot/new-v0") == minari_root / "scorbot" / "new-v0"
    assert not minari_root.exists()
