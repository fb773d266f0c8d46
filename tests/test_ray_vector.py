"""The Ray vector env: the process backend's rollouts exactly, loopback-only networking, failures and restarts.

Ray starts once for the module (2-5 s, actors about 3 s each), with the env's own ``init_ray``."""

import dataclasses
import ipaddress
import os
import signal
import socket
import struct
import sys

import numpy as np
import pytest

from seqdex_drake.envs.factory import make_vector_env
from seqdex_drake.envs.ray_vector import RayVectorEnv, import_ray, init_ray
from seqdex_drake.envs.subtask_env import EnvState, make_env
from seqdex_drake.envs.vector import ProcessVectorEnv, WorkerError
from seqdex_drake.tasks.registry import default_config

TASK, SEED = "grasp", 3
CONFIG = dataclasses.replace(default_config(TASK), episode_length=5)


@pytest.fixture(scope="module")
def ray_instance():
    # Logical CPUs for scheduling: the module's 2-actor env and the 1-actor restart test's env run side by side
    # (with num_cpus=2 the third 1-CPU actor would wait, then fail with WorkerError naming the resources).
    assert init_ray(num_cpus=4), "Ray was already running: this module must start it to check its sockets"
    ray = import_ray()
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def ray_env(ray_instance):
    # A generous answer timeout: an actor imports Drake and builds its station (about 40 s on an idle 2-core
    # machine, over 120 s when other jobs load it); stalls are tested with a short timeout further down.
    with RayVectorEnv(TASK, 2, seed=SEED, config=CONFIG, timeout=600.0) as vector_env:
        yield vector_env


def _rollout(vector_env, actions: np.ndarray) -> list:
    observations, _ = vector_env.reset()
    steps = [(observations,)]
    for action in actions:
        steps.append(vector_env.step(action))
    steps.append(vector_env.reset_at(1, seed=SEED + 10))
    return steps


def test_ray_backend_reproduces_the_process_backend_exactly(ray_env):
    actions = np.random.default_rng(1).uniform(-0.5, 0.5, (7, 2, 19))
    assert ray_env.single_observation_space.shape == (159,) and ray_env.action_space.shape == (2, 19)
    ray_steps = _rollout(ray_env, actions)
    with ProcessVectorEnv(TASK, 2, seed=SEED, config=CONFIG) as process_env:
        process_steps = _rollout(process_env, actions)
    np.testing.assert_array_equal(ray_steps[0][0], process_steps[0][0])
    assert not np.array_equal(ray_steps[0][0][0], ray_steps[0][0][1])  # Env i seeded seed + i.
    for ray_step, process_step in zip(ray_steps[1:-1], process_steps[1:-1], strict=True):
        for ray_part, process_part in zip(ray_step[:4], process_step[:4], strict=True):
            np.testing.assert_array_equal(ray_part, process_part)
        for ray_info, process_info in zip(ray_step[4], process_step[4], strict=True):
            assert ray_info.keys() == process_info.keys()
            assert all(ray_info[key] == process_info[key] for key in ray_info if key.startswith("reward/"))
    assert any(step[3].any() for step in ray_steps[1:-1])  # The horizon crossed an autoreset.
    np.testing.assert_array_equal(ray_steps[-1][0], process_steps[-1][0])  # reset_at, seeded as given:
    np.testing.assert_array_equal(ray_steps[-1][0], make_env(TASK, CONFIG).reset(seed=SEED + 10)[0])
    states = ray_env.get_states()
    assert len(states) == 2 and all(isinstance(state, EnvState) for state in states)


def _descendants(root: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as file:
                    parent = int(file.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(parent, []).append(int(entry))
    found, stack = [], [root]
    while stack:
        pid = stack.pop()
        found.append(pid)
        stack.extend(children.get(pid, []))
    return found


def _address(hex_address: str, version6: bool) -> str:
    packed = bytes.fromhex(hex_address.split(":")[0])
    if version6:  # Four little-endian 32-bit words.
        packed = b"".join(struct.pack("<I", struct.unpack(">I", packed[i:i + 4])[0]) for i in range(0, 16, 4))
        return socket.inet_ntop(socket.AF_INET6, packed)
    return socket.inet_ntop(socket.AF_INET, packed[::-1])


def _inet_sockets(pid: int) -> list[tuple]:
    """(kind, local ip, remote ip, tcp state) of every IPv4/IPv6 socket process ``pid`` holds."""
    inodes = set()
    try:
        for descriptor in os.listdir(f"/proc/{pid}/fd"):
            try:
                target = os.readlink(f"/proc/{pid}/fd/{descriptor}")
            except OSError:
                continue
            if target.startswith("socket:["):
                inodes.add(int(target[8:-1]))
        rows = []
        for kind in ("tcp", "tcp6", "udp", "udp6"):
            with open(f"/proc/{pid}/net/{kind}") as file:
                for line in file.read().splitlines()[1:]:
                    fields = line.split()
                    if int(fields[9]) in inodes:
                        version6 = kind.endswith("6")
                        rows.append((kind, _address(fields[1], version6), _address(fields[2], version6), fields[3]))
        return rows
    except OSError:  # The process ended meanwhile.
        return []


def _loopback(ip: str) -> bool:
    address = ipaddress.ip_address(ip)
    mapped = getattr(address, "ipv4_mapped", None)
    return (mapped or address).is_loopback


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_every_ray_socket_stays_on_loopback(ray_env):
    sockets = {pid: _inet_sockets(pid) for pid in _descendants(os.getpid())}
    assert set(ray_env.pids) <= set(sockets)  # The actors are among the inspected processes.
    rows = [(pid, *row) for pid, pid_rows in sockets.items() for row in pid_rows]
    listeners = [row for row in rows if row[1].startswith("tcp") and row[4] == "0A"]
    assert len(listeners) >= 4, rows  # GCS, raylet, object manager, workers: the check saw Ray's sockets.
    bad = [row for row in rows if not _loopback(row[2])]  # Listening on 0.0.0.0 / :: or an external address.
    bad += [row for row in rows if row[4] != "0A" and not ipaddress.ip_address(row[3]).is_unspecified
            and not _loopback(row[3])]
    assert not bad, f"Ray sockets off loopback (pid, kind, local, remote, state): {bad}"


def test_a_killed_actor_is_restarted_once_then_a_stalled_one_is_reported(ray_instance):
    vector_env = make_vector_env(TASK, 1, seed=SEED, config=CONFIG, backend="ray", max_restarts=1, timeout=600.0)
    assert isinstance(vector_env, RayVectorEnv)
    stopped = None
    try:
        observations, _ = vector_env.reset()
        first_pid = vector_env.pids[0]
        os.kill(first_pid, signal.SIGKILL)
        after, rewards, _, truncated, infos = vector_env.step(np.zeros((1, 19)))
        assert truncated[0] and rewards[0] == 0.0 and infos[0]["worker_restarted"]
        assert "died" in infos[0]["worker_error"] and vector_env.lost_episodes == 1
        np.testing.assert_array_equal(infos[0]["final_observation"], observations[0])
        assert vector_env.pids[0] != first_pid and np.isfinite(after).all()
        stopped, vector_env.timeout = vector_env.pids[0], 2.0
        os.kill(stopped, signal.SIGSTOP)  # Alive but never answers; the restart budget is used up.
        with pytest.raises(WorkerError, match=r"worker 0 failed: no answer within 2 s.*restart budget of 1 used up"):
            vector_env.step(np.zeros((1, 19)))
        assert vector_env.closed
    finally:
        if stopped is not None:
            try:
                os.kill(stopped, signal.SIGCONT)  # Let a stopped actor process (if still there) exit.
            except ProcessLookupError:
                pass
        vector_env.close()
    assert ray_instance.is_initialized()  # The env did not start Ray, so it left it running.


def test_bad_backend_and_missing_ray_are_clear_errors(monkeypatch):
    with pytest.raises(ValueError, match="unknown vector env backend 'mpi'; choose one of process, ray"):
        make_vector_env(TASK, 1, backend="mpi")
    monkeypatch.setitem(sys.modules, "ray", None)  # As if ray were not installed.
    with pytest.raises(ImportError, match=r"needs ray.*seqdex_drake\[distributed\].*backend='process'"):
        RayVectorEnv(TASK, 1)
