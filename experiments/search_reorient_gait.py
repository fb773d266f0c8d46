"""Cross-entropy search for tool Reorient's finger gait (``seqdex_drake/scene/tool_reorient_gait.py``).

A candidate gait is played open loop in the tool Reorient env from ``--starts`` start states (tool Grasp's
successful hand-off states from ``--buffer``, or standalone resets with seeds 0.. without one); its score is minus
the tool's orientation error to the goal (rad), averaged over the episode's last ``TAIL`` steps and over the starts,
with a dropped tool (the episode terminated) scored ``-(pi + 1)``. Each iteration samples ``--population``
Gaussian candidates around the mean, keeps the ``--elites`` best, and moves the mean and std toward them. The best
candidate seen is written to ``--out`` (default: the file the gait module reads) after every iteration with its
score, its success count, the env steps spent and the runs that made it (command, commit, iterations); ``--resume``
continues a search from that file.

    python experiments/search_reorient_gait.py --buffer B.npz [--iterations 12] [--population 32] [--elites 6]
        [--starts 4] [--seed 0] [--workers 2] [--out FILE] [--resume]
"""

import argparse
import datetime
import json
import math
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from seqdex_drake.atomic import atomic_write
from seqdex_drake.tasks.registry import default_config
from seqdex_drake.tasks.scripted.tool_reorient_gait import GAIT_FILE, GaitParameters

TASK = "tool_reorient"
#: Steps at the episode's end whose orientation error is averaged into the score.
TAIL = 15
DROPPED = -(math.pi + 1.0)

_env, _starts = None, None  # Per worker process: the env and the start states.


def _initial_states(buffer: str | None, count: int):
    """``count`` start states from the buffer's successful entries (in order), or None for standalone resets."""
    if buffer is None:
        return None
    from seqdex_drake.chaining.terminal_buffer import TerminalBuffer
    from seqdex_drake.env_state import EnvState

    loaded = TerminalBuffer.load(buffer, expected_task=TASK)
    indices = [i for i in range(len(loaded)) if loaded.successes[i]][:count]
    if len(indices) < count:
        sys.exit(f"search_reorient_gait: {buffer} holds {len(indices)} successful hand-offs, --starts asks {count}")
    return [loaded.state(i, EnvState) for i in indices]


def _init_worker(buffer: str | None, count: int) -> None:
    global _env, _starts
    import torch

    torch.set_num_threads(1)
    from seqdex_drake.envs.subtask_env import make_env

    _env, _starts = make_env(TASK), _initial_states(buffer, count)


def _reset(env, starts, k: int):
    if starts is None:
        return env.reset(seed=k)
    return env.reset(seed=k, options={"initial_state": starts[k]})


def episode_score(env, gait, starts, k: int) -> tuple[float, bool]:
    """Plays ``gait`` from start ``k``: (score, success at the end)."""
    from seqdex_drake.tasks.rewards import goal_errors

    observation, _ = _reset(env, starts, k)
    errors, info = [], {}
    for step in range(env.config.episode_length):
        observation, _, terminated, truncated, info = env.step(gait.act(observation, step))
        if terminated:
            return DROPPED, False
        errors.append(goal_errors(env.observation_values())[1])
        if truncated:
            break
    return -float(np.mean(errors[-TAIL:])), bool(info.get("success", False))


def _evaluate(job: tuple[np.ndarray, int]) -> tuple[float, bool]:
    from seqdex_drake.tasks.scripted.tool_reorient_gait import FingerGait

    vector, k = job
    return episode_score(_env, FingerGait(GaitParameters.from_vector(vector)), _starts, k)


def _hold_center(buffer: str | None, count: int) -> np.ndarray:
    """The mean hand action that holds the start states' hand targets: the search's initial centers."""
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.robots.allegro import unscale_limits_to_action

    env, starts = make_env(TASK), _initial_states(buffer, count)
    try:
        holds = []
        for k in range(count):
            _reset(env, starts, k)
            holds.append(unscale_limits_to_action(env._hand_target))
        return np.clip(np.mean(holds, axis=0), -1.0, 1.0)
    finally:
        env.close()


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).resolve().parents[1]).stdout.strip()
    except OSError:
        return ""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--buffer", help="tool Grasp's hand-off buffer (seqdex collect --task tool_grasp ...)")
    parser.add_argument("--iterations", type=int, default=12)
    parser.add_argument("--population", type=int, default=32)
    parser.add_argument("--elites", type=int, default=6)
    parser.add_argument("--starts", type=int, default=4, help="start states each candidate is scored on")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--out", default=str(GAIT_FILE))
    parser.add_argument("--resume", action="store_true", help="continue the search recorded in --out")
    args = parser.parse_args()
    if min(args.iterations, args.population, args.elites, args.starts, args.workers) < 1 \
            or args.elites > args.population:
        parser.error("--iterations, --population, --elites, --starts and --workers must be >= 1, "
                     "and --elites <= --population")
    if args.buffer is not None and not Path(args.buffer).is_file():
        parser.error(f"--buffer {args.buffer}: no such file; make one with seqdex collect --task tool_grasp")
    out = Path(args.out)
    if out.exists() and not out.is_file() or not out.parent.is_dir():
        parser.error(f"--out {out}: not a writable file path")
    rng = np.random.default_rng(args.seed)
    n = GaitParameters.SIZE
    if args.resume:
        try:
            record = json.loads(out.read_text())
            mean, std = np.asarray(record["search"]["mean"]), np.asarray(record["search"]["std"])
            done, steps, runs = record["search"]["iterations"], record["env_steps"], record.get("runs", [])
            best = {key: record[key] for key in ("gait", "score", "successes", "starts")}
            rng = np.random.default_rng([args.seed, done])
        except (OSError, ValueError, KeyError) as error:
            parser.error(f"--resume: {out} holds no search to continue ({error})")
    else:
        center = _hold_center(args.buffer, args.starts)
        mean = np.r_[center, np.zeros(16), np.zeros(16), 40.0]
        std = np.r_[np.full(16, 0.15), np.full(16, 0.3), np.full(16, np.pi), 20.0]
        done, steps, best, runs = 0, 0, None, []
    floor = np.r_[np.full(16, 0.02), np.full(16, 0.02), np.full(16, 0.1), 2.0]
    episode_length = default_config(TASK).episode_length
    context = multiprocessing.get_context("spawn")
    with context.Pool(args.workers, initializer=_init_worker, initargs=(args.buffer, args.starts)) as pool:
        for iteration in range(done, done + args.iterations):
            start = time.perf_counter()
            candidates = mean + std * rng.standard_normal((args.population, n))
            if iteration == 0:
                candidates[0] = mean  # The hold itself is scored too.
            jobs = [(c, k) for c in candidates for k in range(args.starts)]
            results = np.array(pool.map(_evaluate, jobs), dtype=object).reshape(args.population, args.starts, 2)
            scores = results[:, :, 0].astype(float).mean(axis=1)
            successes = results[:, :, 1].astype(bool).sum(axis=1)
            steps += len(jobs) * episode_length  # At most: a dropped tool ends its episode early.
            elite = np.argsort(scores)[::-1][:args.elites]
            mean = 0.3 * mean + 0.7 * candidates[elite].mean(axis=0)
            std = np.maximum(0.3 * std + 0.7 * candidates[elite].std(axis=0), floor)
            top = int(elite[0])
            if best is None or scores[top] > best["score"]:
                best = {"gait": GaitParameters.from_vector(candidates[top]).to_dict(), "score": float(scores[top]),
                        "successes": int(successes[top]), "starts": args.starts}
            run = {"command": " ".join(["python", "experiments/search_reorient_gait.py", *sys.argv[1:]]),
                   "commit": _commit(), "date": datetime.date.today().isoformat(),
                   "iterations": [done + 1, iteration + 1]}
            record = {**best, "buffer": args.buffer, "env_steps": steps, "runs": [*runs, run],
                      "search": {"iterations": iteration + 1, "mean": mean.tolist(), "std": std.tolist()}}
            text = json.dumps(record, indent=1) + "\n"
            atomic_write(out, lambda file, text=text: file.write(text.encode()))
            print(f"iteration {iteration + 1}: best {scores[top]:+.3f} ({successes[top]}/{args.starts} succeed), "
                  f"elite mean {scores[elite].mean():+.3f}, all-time {best['score']:+.3f}, "
                  f"{time.perf_counter() - start:.0f} s, {steps} env steps", flush=True)


if __name__ == "__main__":
    main()
