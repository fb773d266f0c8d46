"""Issue 17, items 8-11: resuming before the first checkpoint, bad input refused up front (one line, exit 2, nothing
left behind), one training per run directory (a lock naming the holder), and interrupts that save the run
(SIGINT / SIGTERM between updates, Ctrl-C reaching the workers too, wall-clock checkpoints)."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from seqdex_drake.cli.main import main
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.rl.toy_env import TargetVectorEnv

REPO = Path(__file__).resolve().parents[1]
SIMULATE = REPO / "scripts" / "simulate_chain.py"
RUNNER = Path(__file__).with_name("crash_resume_runner.py")
TRAIN = ["train", "--task", "reach", "--test", "--num-envs", "1"]


@pytest.fixture(scope="module")
def reach_run(tmp_path_factory) -> Path:
    """A tiny trained reach run (``seqdex train --test``, one update)."""
    run_dir = tmp_path_factory.mktemp("robust") / "reach"
    assert main([*TRAIN, "--run-dir", str(run_dir)]) == 0
    return run_dir


def _tree(directory: Path) -> dict[str, str]:
    """Every path under ``directory`` with its content digest (directories: 'dir')."""
    return {str(path.relative_to(directory)): "dir" if path.is_dir() else hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(directory.rglob("*"))}


def _counters(path: Path) -> dict:
    return torch.load(path, weights_only=True)["counters"]


# ----------------------------------------------------------------------------------- item 9: bad input
# (argv with {run} / {tmp} placeholders, text the one-line message must contain)
CLI_ROWS = [
    ([*TRAIN, "--steps", "-5", "--run-dir", "{tmp}/new"], "--steps must be >= 1, got -5"),
    ([*TRAIN, "--steps", "0", "--run-dir", "{tmp}/new"], "--steps must be >= 1, got 0"),
    (["train", "--task", "reach", "--test", "--num-envs", "0", "--run-dir", "{tmp}/new"], "--num-envs must be >= 1"),
    ([*TRAIN, "--seed", "-1", "--run-dir", "{tmp}/new"], "--seed must be in 0 .. "),
    ([*TRAIN, "--envs-per-worker", "0", "--run-dir", "{tmp}/new"], "--envs-per-worker must be >= 1"),
    ([*TRAIN, "--checkpoint-seconds", "0", "--run-dir", "{tmp}/new"], "--checkpoint-seconds must be > 0"),
    ([*TRAIN, "--run-dir", "{tmp}/afile"], "is a file, not a directory"),
    ([*TRAIN, "--run-dir", "{tmp}/afile/run"], "afile is a file, not a directory"),
    ([*TRAIN, "--run-dir", "/sys/seqdex_robustness/run"], "cannot write in /sys"),  # Read-only, also for root.
    ([*TRAIN, "--resume", "--run-dir", "{tmp}/truncated"], "config.json is unreadable or truncated"),
    (["collect", "--task", "reach", "--test", "--checkpoint", "{run}/last.pt", "--out", "{tmp}/afile/b.npz"],
     "afile is a file, not a directory"),
    (["collect", "--task", "reach", "--test", "--checkpoint", "{run}/last.pt", "--out", "{tmp}/b.npz", "--seed",
      "-1"], "--seed must be in 0 .. "),
]


@pytest.mark.parametrize("argv, text", CLI_ROWS, ids=[f"{row[0][0]} #{i}" for i, row in enumerate(CLI_ROWS)])
def test_cli_bad_input_is_refused_before_anything_is_created(reach_run, tmp_path, capsys, argv, text):
    (tmp_path / "afile").write_text("not a directory")
    shutil.copytree(reach_run, tmp_path / "truncated")
    record = (tmp_path / "truncated" / "config.json").read_text()
    (tmp_path / "truncated" / "config.json").write_text(record[: len(record) // 2])  # A crash mid-write.
    before, run_before = _tree(tmp_path), _tree(reach_run)
    argv = [a.replace("{run}", str(reach_run)).replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert _tree(tmp_path) == before and _tree(reach_run) == run_before  # Nothing created, nothing changed.
    assert not Path("/sys/seqdex_robustness").exists()


@pytest.mark.parametrize("text, message", [
    ('{random_seed: "abc"}', "invalid literal"),
    ("{random_seed: -1}", "random_seed must be >= 0"),
    ("{plant_config: {time_step: .nan}}", "plant_config.time_step must be finite"),
    ("{plant_config: {time_step: .inf}}", "plant_config.time_step must be finite"),
    ("{robot: {arm_kp: .nan}}", "robot.arm_kp must be finite"),
    ("{robot: {hand_kd: -1.0}}", "robot.hand_kd must be >= 0"),
    ("{robot: {arm_home: [.nan, 0, 0, 0, 0, 0, 0]}}", r"robot.arm_home\[0\] must be finite"),
    ("{plant_config: 5}", "wrong kind"),
])
def test_scenario_values_are_validated(text, message):
    from seqdex_drake.scenario import LoadScenario, ScenarioError

    with pytest.raises(ScenarioError, match=message):
        LoadScenario("handover/reach", scenario_text=text)


@pytest.mark.parametrize("field, value", [("episode_length", -5), ("episode_length", 0), ("episode_length", 2.5),
                                          ("ema", 0.0), ("ema", 1.5), ("ema", float("nan")), ("wrist_step", 0.0),
                                          ("hover_height", -0.1), ("drop_height", float("inf")),
                                          ("object_types", []), ("success_threshold", [float("nan")])])
def test_task_config_refuses_values_no_episode_runs_with(field, value):
    import dataclasses

    from seqdex_drake.tasks.base import TaskConfig
    from seqdex_drake.tasks.registry import default_config

    with pytest.raises(ValueError, match=f"{field} must be"):
        TaskConfig(**{field: value})
    with pytest.raises(ValueError, match=f"TaskConfig reach: {field} must be"):
        dataclasses.replace(default_config("reach"), **{field: value})


@pytest.mark.parametrize("args, message", [
    (["--seed", "-1", "--headless"], "--seed must be in 0 .. "),
    (["--port", "70000"], "--port must be in 1024 .. 65535, got 70000"),
    (["--port", "1"], "--port must be in 1024 .. 65535, got 1"),
    (["--manual", "{binary}", "--headless"], "cannot read it as a YAML assembly manual (not a text file)"),
    (["--record", "{tmp}/afile/replay.html"], "afile is a file, not a directory"),
    (["--checkpoints", "{tmp}/afile", "--headless"], "afile is a file, not a directory"),
    (["--checkpoints", "{tmp}/nowhere", "--headless"], "nowhere does not exist"),
    (["--max-switches", "-1", "--headless"], "--max-switches must be >= 0"),
    (["--trigger", "often", "--headless"], "invalid choice: 'often'"),
    (["--record", "{tmp}/replay.html", "--headless"], "--record needs meshcat"),
])
def test_simulate_chain_refuses_bad_input_up_front(tmp_path, args, message):
    (tmp_path / "afile").write_text("not a directory")
    (tmp_path / "binary.yaml").write_bytes(bytes(range(256)) * 4)
    args = [a.replace("{tmp}", str(tmp_path)).replace("{binary}", str(tmp_path / "binary.yaml")) for a in args]
    before = _tree(tmp_path)
    result = subprocess.run([sys.executable, str(SIMULATE), "--test", *args], capture_output=True, text=True,
                            timeout=120, cwd=REPO)
    assert result.returncode == 2, result.stderr[-2000:]
    assert message in result.stderr and "Traceback" not in result.stderr
    assert "building the" not in result.stdout  # Refused before the (slow) build.
    assert _tree(tmp_path) == before


# --------------------------------------------------------------------- item 8: resume before a checkpoint
def test_resume_of_a_run_without_checkpoint_starts_at_step_zero(reach_run, tmp_path, capsys):
    run_dir = tmp_path / "crashed"
    shutil.copytree(reach_run, run_dir)
    for name in ("last.pt", "best.pt"):  # A crash before the first checkpoint leaves config.json only.
        (run_dir / name).unlink()
    record = json.loads((run_dir / "config.json").read_text())
    # Another config than the saved one is still refused (here: the full-length episodes of a run without --test).
    assert main(["train", "--task", "reach", "--run-dir", str(run_dir), "--resume"]) == 2
    assert "task config differs" in capsys.readouterr().err
    assert not (run_dir / "last.pt").exists()
    assert main([*TRAIN, "--run-dir", str(run_dir), "--resume", "--seed", "7"]) == 0
    captured = capsys.readouterr()
    assert "has no checkpoint yet" in captured.err and "step 0 with its saved config" in captured.err
    assert "seed 0 (--seed 7 ignored)" in captured.err
    batch = record["ppo"]["num_envs"] * record["ppo"]["horizon"]
    assert f"steps 0 -> {batch}" in captured.out
    assert _counters(run_dir / "last.pt")["global_step"] == batch
    assert json.loads((run_dir / "config.json").read_text()) == record


# ------------------------------------------------------------------------------ item 10: run-directory lock
def test_a_locked_run_directory_refuses_a_second_training(reach_run, tmp_path, capsys):
    from seqdex_drake.cli.run_lock import RunLock

    run_dir = tmp_path / "busy"
    shutil.copytree(reach_run, run_dir)
    before = _tree(run_dir)
    with RunLock(run_dir):  # Another training holds it (as if it ran in this process).
        for argv in ([*TRAIN, "--run-dir", str(run_dir), "--resume"], [*TRAIN, "--run-dir", str(run_dir)]):
            assert main(argv) == 2
            err = capsys.readouterr().err
            assert f"is in use by process {os.getpid()} on host " in err and "Traceback" not in err
        assert _counters(run_dir / "last.pt") == _counters(reach_run / "last.pt")
    assert {k: v for k, v in _tree(run_dir).items() if k != ".lock"} == {k: v for k, v in before.items()
                                                                          if k != ".lock"}


def test_the_lock_dies_with_its_holder(tmp_path):
    from seqdex_drake.cli.run_lock import RunLock
    from seqdex_drake.user_input import InputError

    code = (f"from seqdex_drake.cli.run_lock import RunLock\nlock = RunLock({str(tmp_path / 'run')!r}, create=True)\n"
            "lock.acquire()\nprint('locked', flush=True)\nimport time\ntime.sleep(600)\n")
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(InputError, match=f"process {holder.pid} on host"):
            RunLock(tmp_path / "run").acquire()
        holder.kill()  # A crash: no chance to release.
        holder.wait(timeout=30)
        with RunLock(tmp_path / "run"):
            pass
    finally:
        if holder.poll() is None:
            holder.kill()


# -------------------------------------------------------------------------------- item 11: interrupts
def _descendants(pid: int) -> set[int]:
    """The live process tree under ``pid`` (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                children.setdefault(int(fields[1]), []).append(int(entry.name))
    found, frontier = set(), [pid]
    while frontier:
        for child in children.get(frontier.pop(), []):
            found.add(child)
            frontier.append(child)
    return found


def _alive(pid: int) -> bool:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _start_training(run_dir: Path, new_session: bool = False) -> subprocess.Popen:
    """``seqdex train`` on reach with a budget it will not finish; returns once its first update is done."""
    process = subprocess.Popen([sys.executable, "-m", "seqdex_drake.cli.main", *TRAIN, "--num-envs", "2",
                                "--run-dir", str(run_dir), "--steps", "10000000", "--checkpoint-seconds", "3600"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                               start_new_session=new_session)
    deadline = time.monotonic() + 240
    while not (run_dir / "best.pt").is_file():  # Written after the first update.
        assert process.poll() is None, process.communicate()[1][-2000:]
        assert time.monotonic() < deadline, "no update in 240 s"
        time.sleep(0.2)
    return process


def _check_stopped(process: subprocess.Popen, run_dir: Path, name: str, code: int, workers: set[int]) -> None:
    try:
        out, err = process.communicate(timeout=180)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == code, err[-2000:]
    assert "Traceback" not in err, err[-3000:]
    line = next(line for line in err.splitlines() if line.startswith(f"seqdex train: {name}: saved "))
    step, updates = int(line.split(" at step ")[1].split()[0]), int(line.split(" (")[1].split()[0])
    assert step > 0 and "continue with seqdex train --task reach" in line and "--resume" in line
    counters = _counters(run_dir / "last.pt")  # The state at the stop, not an older periodic checkpoint.
    assert (counters["global_step"], counters["num_updates"]) == (step, updates)
    deadline = time.monotonic() + 30
    while any(_alive(pid) for pid in workers):  # Workers, fork server and resource tracker all ended.
        assert time.monotonic() < deadline, f"processes left behind: {[p for p in workers if _alive(p)]}"
        time.sleep(0.2)


def test_sigterm_saves_last_pt_closes_the_workers_and_releases_the_lock(tmp_path, capsys):
    from seqdex_drake.cli.run_lock import RunLock

    run_dir = tmp_path / "run"
    process = _start_training(run_dir)
    try:
        workers = _descendants(process.pid)
        assert len(workers) >= 2
        assert main([*TRAIN, "--run-dir", str(run_dir), "--resume"]) == 2  # A second training is refused ...
        assert f"is in use by process {process.pid}" in capsys.readouterr().err  # ... naming the first.
        assert json.loads((run_dir / "config.json").read_text())["ppo"]["checkpoint_seconds"] == 3600
        process.send_signal(signal.SIGTERM)
        _check_stopped(process, run_dir, "SIGTERM", 128 + signal.SIGTERM, workers)
    finally:
        if process.poll() is None:
            process.kill()
    with RunLock(run_dir):  # Released at the exit.
        pass


def test_ctrl_c_in_a_terminal_saves_last_pt_although_the_workers_get_it_too(tmp_path):
    """A terminal sends SIGINT to the whole foreground process group: the env workers exit at once, the rollout in
    progress fails, and the trainer saves the learner as its last update left it."""
    run_dir = tmp_path / "run"
    process = _start_training(run_dir, new_session=True)
    try:
        workers = _descendants(process.pid)
        time.sleep(1.0)  # Most likely inside a rollout now.
        os.killpg(process.pid, signal.SIGINT)
        _check_stopped(process, run_dir, "SIGINT", 128 + signal.SIGINT, workers)
    finally:
        if process.poll() is None:
            process.kill()
    resumed = PPO.resume(run_dir / "last.pt")
    assert resumed.stats.num_episodes > 0 and "over the last" in resumed.stats.summary()


def _records(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []


def test_sigint_between_updates_saves_the_exact_state(tmp_path):
    """PPO.train on the toy env (tests/crash_resume_runner.py, no handlers of its own): a SIGINT to the trainer
    finishes the update in progress and saves last.pt at that update (not at the last multiple of checkpoint_every)
    before it raises KeyboardInterrupt as it did; resuming reproduces the uninterrupted run's updates exactly."""
    updates = 7
    _run = [sys.executable, str(RUNNER)]
    subprocess.run([*_run, str(tmp_path / "full"), str(tmp_path / "full.jsonl"), "--updates", str(updates)],
                   check=True, timeout=300)
    uninterrupted = _records(tmp_path / "full.jsonl")
    run_dir, log = tmp_path / "run", tmp_path / "log.jsonl"
    process = subprocess.Popen([*_run, str(run_dir), str(log), "--updates", str(updates), "--pause", "0.5"],
                               stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while len(_records(log)) < 3:
            assert process.poll() is None and time.monotonic() < deadline, process.stderr.read()[-2000:]
            time.sleep(0.02)
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=120) == -signal.SIGINT, process.stderr.read()[-2000:]
        assert "KeyboardInterrupt" in process.stderr.read()  # The caller still sees the interrupt.
    finally:
        if process.poll() is None:
            process.kill()
    stopped_at = len(_records(log))
    assert 3 <= stopped_at < updates
    assert PPO.resume(run_dir / "last.pt").num_updates == stopped_at  # checkpoint_every is 2: odd counts too.
    subprocess.run([*_run, str(run_dir), str(tmp_path / "resumed.jsonl"), "--updates", str(updates), "--resume"],
                   check=True, timeout=300)
    resumed = _records(tmp_path / "resumed.jsonl")
    assert [record["update"] for record in resumed] == list(range(stopped_at + 1, updates + 1))
    for record in resumed:
        assert record["metrics"] == uninterrupted[record["update"] - 1]["metrics"], record["update"]


def _toy_config(**overrides) -> PPOConfig:
    return PPOConfig(actor_hidden_sizes=(16,), critic_hidden_sizes=(16,), num_envs=2, horizon=8, num_epochs=1,
                     num_minibatches=1, stats_window=4, **overrides)


def test_checkpoint_seconds_writes_last_pt_by_wall_clock(tmp_path):
    ppo = PPO.for_env(_toy_config(checkpoint_every=1000, checkpoint_seconds=1e-9), TargetVectorEnv(num_envs=2))
    saved = []
    ppo.train(TargetVectorEnv(num_envs=2), tmp_path, total_steps=3 * 16, progress=False,
              callbacks=[lambda learner, _: saved.append(_counters(tmp_path / "last.pt")["num_updates"])])
    assert saved == [1, 2, 3]  # Every update is over 1 ns after the last write.
    ppo = PPO.for_env(_toy_config(checkpoint_every=1000, checkpoint_seconds=3600.0), TargetVectorEnv(num_envs=2))
    ppo.train(TargetVectorEnv(num_envs=2), tmp_path / "hourly", total_steps=3 * 16, progress=False,
              callbacks=[lambda learner, _: saved.append((tmp_path / "hourly" / "last.pt").exists())])
    assert saved[3:] == [False, False, False]  # Only the final write.


def test_a_resumed_run_stopped_before_its_first_update_reports_the_saved_window(tmp_path):
    from seqdex_drake.rl.stop_signals import StopSignals

    ppo = PPO.for_env(_toy_config(), TargetVectorEnv(num_envs=2))
    assert ppo.stats.summary() == "no episodes yet"
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    ppo.train(TargetVectorEnv(num_envs=2), tmp_path, total_steps=4 * 16, progress=False)
    assert {sig: signal.getsignal(sig) for sig in handlers} == handlers  # Installed for the call only.
    resumed = PPO.resume(tmp_path / "last.pt")
    stop = StopSignals()
    stop.request(signal.SIGTERM)
    metrics = resumed.train(TargetVectorEnv(num_envs=2), tmp_path, total_steps=10 * 16, progress=False, stop=stop)
    assert resumed.num_updates == 4  # Stopped before any update ...
    assert metrics["charts/success_rate"] == pytest.approx(sum(ppo.stats.successes) / len(ppo.stats.successes))
    assert resumed.stats.summary() == ppo.stats.summary() and "over the last" in resumed.stats.summary()


def test_stop_signals_leave_an_ignored_signal_ignored():
    from seqdex_drake.rl.stop_signals import StopSignals

    interrupt_handler = signal.getsignal(signal.SIGINT)
    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)  # As for a job a script started in the background.
    try:
        with StopSignals() as stop:
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGINT) == stop._handle
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
            assert stop.received is None
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            assert stop.received == "SIGINT" and stop.exit_code == 130
        assert signal.getsignal(signal.SIGINT) == interrupt_handler
    finally:
        signal.signal(signal.SIGTERM, previous)
