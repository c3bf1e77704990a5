"""Output folders: one run at a time (a lock the OS drops with its process), results published whole, and
a second `bench` or `sweep` into a folder in use refused with exit status 2 and one line naming it."""
from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from ftcgym.benchmark.outputs import LOCK_FILE, MANIFEST_FILE, FolderInUse, OutputFolder, atomic_write_text
from ftcgym.cli import main

REPO = Path(__file__).resolve().parents[1]
TINY_BENCH = ["--scenario", "quad-hover", "--episodes", "1", "--workers", "1",
              "--env-kwargs", '{"max_episode_seconds": 0.3}']
HOLDER = """
import sys
from ftcgym.benchmark.outputs import OutputFolder
with OutputFolder(sys.argv[1]):
    print("locked", flush=True)
    sys.stdin.read()
"""


@pytest.fixture
def held(tmp_path):
    """The folder's lock taken through an open file of its own, as another process would hold it."""
    folder = tmp_path / "out"
    folder.mkdir()
    with open(folder / LOCK_FILE, "w") as file:
        fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        yield folder


def one_line_naming(folder, capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(folder) in err and "in use" in err
    return err


def test_a_second_bench_into_a_folder_in_use_exits_2_at_once(held, capsys):
    assert main(["bench", *TINY_BENCH, "--out", str(held)]) == 2
    assert one_line_naming(held, capsys).startswith(f"ftcgym bench: {held} is in use by another ftcgym run")
    assert sorted(p.name for p in held.iterdir()) == [LOCK_FILE]   # nothing flown, nothing written


def test_a_second_sweep_into_a_folder_in_use_exits_2_before_looking_at_it(held, tmp_path, capsys):
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump({"scenarios": {"quad-hover": 1}, "parameter_sets": [{"name": "a"}]}))
    assert main(["sweep", str(config), "--out", str(held), "--no-progress"]) == 2
    one_line_naming(held, capsys)
    assert sorted(p.name for p in held.iterdir()) == [LOCK_FILE]   # no sweep_config.json: it never claimed it


def test_a_second_train_into_a_folder_in_use_exits_2_before_building_anything(held, capsys):
    assert main(["train", "--config", "rotor-loss-recovery", "--out", str(held), "--no-progress"]) == 2
    one_line_naming(held, capsys)
    assert sorted(p.name for p in held.iterdir()) == [LOCK_FILE]


def test_the_error_names_the_holders_pid_and_a_killed_holder_leaves_no_lock(tmp_path, capsys):
    folder = tmp_path / "out"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert holder.stdout.readline() == "locked\n"
        with pytest.raises(FolderInUse, match=rf"{folder} is in use by another ftcgym run \(pid {holder.pid}\)"):
            OutputFolder(folder).__enter__()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with OutputFolder(folder):   # the OS released it with the process
        pass


def test_the_lock_is_released_after_a_run_and_nests_within_one(tmp_path):
    for _ in range(2):
        with OutputFolder(tmp_path) as outer, OutputFolder(tmp_path):   # the CLI around a library call
            pass
        with open(tmp_path / LOCK_FILE) as file:
            fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)   # free again
    assert outer.path == tmp_path and (tmp_path / LOCK_FILE).exists()   # kept: deleting it would race


def test_a_relative_folder_is_released_after_the_block_changed_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with OutputFolder("out"):
        monkeypatch.chdir("/")                       # the lock's key was looked up anew: KeyError, lock kept
    with open(tmp_path / "out" / LOCK_FILE) as file:
        fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)


def publish_run(folder, files: dict, also=()):
    with OutputFolder(folder) as run:
        for name, text in files.items():
            run.staged(name).write_text(text)
        return run.publish(also)


def test_a_run_replaces_the_previous_runs_files_whole(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")   # not written by a run: left alone
    publish_run(tmp_path, {"results.json": "1", "a.png": "1", "a-event.png": "1"})
    (tmp_path / "journal.jsonl").write_text("in place")
    assert publish_run(tmp_path, {"results.json": "2", "b.png": "2"}, also=("journal.jsonl",)) == [
        "b.png", "journal.jsonl", "results.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [LOCK_FILE, MANIFEST_FILE, "notes.txt", "journal.jsonl", "results.json", "b.png"])
    assert (tmp_path / "results.json").read_text() == "2"
    publish_run(tmp_path, {"results.json": "3"})
    assert not (tmp_path / "journal.jsonl").exists() and not (tmp_path / "b.png").exists()


def test_a_run_that_fails_before_publishing_leaves_the_previous_results(tmp_path):
    publish_run(tmp_path, {"results.json": "1"})
    with pytest.raises(RuntimeError), OutputFolder(tmp_path) as run:
        run.staged("results.json").write_text("half")
        raise RuntimeError("crash")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([LOCK_FILE, MANIFEST_FILE, "results.json"])
    assert (tmp_path / "results.json").read_text() == "1"


def test_a_manifest_cannot_name_files_outside_the_folder(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("keep")
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / MANIFEST_FILE).write_text(json.dumps(["../outside.txt", "/etc/hosts", LOCK_FILE]))
    publish_run(folder, {"results.json": "1"})
    assert outside.read_text() == "keep" and (folder / LOCK_FILE).exists()


def test_atomic_write_leaves_no_temporary_file(tmp_path, monkeypatch):
    path = tmp_path / "study.json"
    atomic_write_text(path, "old")
    atomic_write_text(path, "new")
    assert [p.name for p in tmp_path.iterdir()] == ["study.json"] and path.read_text() == "new"

    def fail(*args):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_text(path, "newer")
    assert [p.name for p in tmp_path.iterdir()] == ["study.json"] and path.read_text() == "new"


@pytest.mark.parametrize("inside", ["", "sub"])
def test_a_file_where_the_output_folder_goes_is_named(tmp_path, inside):
    (tmp_path / "results").write_text("not a folder")
    out = tmp_path / "results" / inside if inside else tmp_path / "results"
    with pytest.raises(ValueError, match=f"--out {out}: a file is in the way"), OutputFolder(out):
        pass
