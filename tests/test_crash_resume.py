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
