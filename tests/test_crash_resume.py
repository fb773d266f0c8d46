"""A training process killed with SIGKILL mid-run leaves a loadable run directory; resuming it continues the
counters and reproduces the uninterrupted run's updates exactly (same seed, toy env state in the checkpoint)."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from seqdex_drake.rl.ppo import PPO

RUNNER = Path(__file__).with_name("crash_resume_runner.py")
UPDATES = 7
STEPS_PER_UPDATE = 4 * 8


def _run(run_dir: Path, log: Path, *extra: str) -> None:
    subprocess.run([sys.executable, str(RUNNER), str(run_dir), str(log), "--updates", str(UPDATES), *extra],
                   check=True, timeout=300)


def _records(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []


def _kill_mid_run(run_dir: Path, log: Path, after_updates: int) -> None:
    process = subprocess.Popen([sys.executable, str(RUNNER), str(run_dir), str(log), "--updates", str(UPDATES),
                                "--pause", "0.3"])
    try:
        deadline = time.monotonic() + 240
        while len(_records(log)) < after_updates:
            assert process.poll() is None, f"the runner exited early with code {process.returncode}"
            assert time.monotonic() < deadline, "the runner made no progress"
            time.sleep(0.02)
        process.send_signal(signal.SIGKILL)
        assert process.wait(timeout=60) == -signal.SIGKILL
    finally:
        if process.poll() is None:
            process.kill()


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> list[dict]:
    directory = tmp_path_factory.mktemp("uninterrupted")
    _run(directory / "run", directory / "log.jsonl")
    records = _records(directory / "log.jsonl")
    assert [record["update"] for record in records] == list(range(1, UPDATES + 1))
    return records


def test_killed_run_resumes_and_matches_the_uninterrupted_run(tmp_path, uninterrupted):
    run_dir, log = tmp_path / "run", tmp_path / "log.jsonl"
    _kill_mid_run(run_dir, log, after_updates=3)
    killed_at = len(_records(log))
    assert killed_at < UPDATES  # Killed mid-run, not after the end.

    checkpoint = PPO.resume(run_dir / "last.pt")  # Loadable despite the SIGKILL (atomic writes).
    saved = checkpoint.num_updates
    assert 2 <= saved <= killed_at and saved % 2 == 0  # checkpoint_every = 2: the last even update reached.
    assert checkpoint.global_step == saved * STEPS_PER_UPDATE
    assert checkpoint.stats.num_episodes == uninterrupted[saved - 1]["num_episodes"]

    resumed_log = tmp_path / "resumed.jsonl"
    _run(run_dir, resumed_log, "--resume")
    resumed = _records(resumed_log)
    # Counters continue from the checkpoint; updates done after it and lost in the kill are redone.
    assert [record["update"] for record in resumed] == list(range(saved + 1, UPDATES + 1))
    assert [record["global_step"] for record in resumed] == [u * STEPS_PER_UPDATE for u in range(saved + 1,
                                                                                                    UPDATES + 1)]
    # Every metric (losses, rewards, episode statistics) equals the uninterrupted run's, bit for bit.
    for record in resumed:
        expected = uninterrupted[record["update"] - 1]
        assert record["num_episodes"] == expected["num_episodes"]
        assert record["metrics"] == expected["metrics"], f"update {record['update']} differs after the resume"
    # The updates the killed process logged before dying match too (the same run up to the kill).
    assert _records(log)[:killed_at] == uninterrupted[:killed_at]
    assert PPO.resume(run_dir / "last.pt").num_updates == UPDATES


def test_resuming_without_the_env_state_does_not_match(tmp_path, uninterrupted):
    """The control: the exact match above needs the env state from the checkpoint (so that test can fail)."""
    run_dir = tmp_path / "run"
    subprocess.run([sys.executable, str(RUNNER), str(run_dir), str(tmp_path / "first.jsonl"), "--updates", "2"],
                   check=True, timeout=300)
    assert _records(tmp_path / "first.jsonl") == uninterrupted[:2]
    _run(run_dir, tmp_path / "resumed.jsonl", "--resume", "--fresh-env")
    resumed = _records(tmp_path / "resumed.jsonl")
    assert resumed[0]["update"] == 3 and resumed[0]["global_step"] == uninterrupted[2]["global_step"]
    assert resumed[0]["metrics"]["losses/value"] != uninterrupted[2]["metrics"]["losses/value"]


def _writer_blocked_mid_write(path: Path) -> subprocess.Popen:
    """A process stuck inside ``atomic_write(path)`` after writing half a file (its temporary file exists)."""
    code = ("import sys, time\nfrom seqdex_drake.atomic import atomic_write\n"
            "def write(file):\n    file.write(b'half'); file.flush(); print('writing', flush=True); time.sleep(600)\n"
            f"atomic_write({str(path)!r}, write)\n")
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline().strip() == "writing"
    return process


def _temporaries(path: Path) -> list[str]:
    return sorted(name.name for name in path.parent.glob(f".{path.name}.*.tmp"))


def test_a_killed_writers_temporary_file_is_removed_by_the_next_write(tmp_path):
    from seqdex_drake.atomic import atomic_write

    path = tmp_path / "last.pt"
    atomic_write(path, lambda file: file.write(b"first"))
    killed, alive = _writer_blocked_mid_write(path), _writer_blocked_mid_write(path)
    try:
        killed.kill()
        killed.wait(timeout=30)
        stale = [name for name in _temporaries(path) if f".{killed.pid}." in name]
        assert len(stale) == 1 and len(_temporaries(path)) == 2  # SIGKILL leaves the temporary file behind.
        assert path.read_bytes() == b"first"  # ... and the destination untouched.
        atomic_write(path, lambda file: file.write(b"second"))
        assert path.read_bytes() == b"second"
        remaining = _temporaries(path)
        assert len(remaining) == 1 and f".{alive.pid}." in remaining[0]  # A live writer's file is left alone.
    finally:
        for process in (killed, alive):
            process.kill()
            process.wait(timeout=30)
