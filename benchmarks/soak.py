"""Training soak: PPO on a sub-task's vector env for ``--minutes``, watching resident memory (RSS) for leaks.

The learner (this process) and every worker's RSS (``VmRSS`` from /proc) are read after the first update
(``start``: imports, env builds, allocator pools and the first checkpoint-free rollout are warm by then), after
every update, and at the end. A checkpoint is written every ``--checkpoint-every`` updates into a temporary run
directory, as a real run does. ``drift_percent`` is (end - start) / start for the learner, the workers together
and everything together (goal < 5 % over an hour). Networks are small (64-64) so the soak exercises the envs,
the vector env, the rollout buffer and checkpointing rather than matrix products.

The last line is one JSON object with the figures.

    python benchmarks/soak.py [--minutes 60] [--task grasp] [--workers 2] [--backend process|ray] [--test]
"""

import argparse
import json
import tempfile
import time

from seqdex_drake.envs.factory import BACKENDS, make_vector_env
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO


def rss_mib(pid: int | str = "self") -> float:
    """Resident set size of process ``pid`` in MiB (0 if it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as file:
            for line in file:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def sample(vector_env) -> dict:
    workers = [rss_mib(pid) for pid in vector_env.pids]
    learner = rss_mib()
    return {"learner": learner, "workers": sum(workers), "total": learner + sum(workers),
            "per_worker": [round(value, 1) for value in workers]}


def drift(start: dict, end: dict) -> dict:
    return {key: round(100.0 * (end[key] - start[key]) / start[key], 2) for key in ("learner", "workers", "total")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--task", default="grasp")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--backend", choices=BACKENDS, default="process")
    parser.add_argument("--checkpoint-every", type=int, default=10)
    parser.add_argument("--test", action="store_true", help="about 20 seconds")
    args = parser.parse_args()
    if args.test:
        args.minutes = min(args.minutes, 0.33)
    config = PPOConfig.for_task(args.task, num_envs=args.workers, seed=0, actor_hidden_sizes=(64, 64),
                                critic_hidden_sizes=(64, 64), checkpoint_every=args.checkpoint_every)
    vector_env = make_vector_env(args.task, args.workers, seed=0, backend=args.backend)
    samples, started = [], {}

    def watch(learner: PPO, metrics: dict) -> bool:
        samples.append(sample(vector_env))
        if learner.num_updates == 1:
            started["time"], started["step"] = time.monotonic(), learner.global_step
            return True
        return time.monotonic() - started["time"] < 60.0 * args.minutes

    try:
        ppo = PPO.for_env(config, vector_env)
        with tempfile.TemporaryDirectory(prefix="seqdex-soak-") as run_dir:
            ppo.train(vector_env, run_dir, total_steps=10**12, callbacks=[watch], progress=False)
            end = sample(vector_env)
    finally:
        vector_env.close()
    start, elapsed = samples[0], time.monotonic() - started["time"]
    peak = max(entry["total"] for entry in samples)
    print(f"start: learner {start['learner']:.1f} MiB, workers {start['per_worker']} MiB")
    print(f"end:   learner {end['learner']:.1f} MiB, workers {end['per_worker']} MiB after {elapsed / 60:.1f} min, "
          f"{ppo.num_updates} updates, {ppo.global_step} env steps")
    print(json.dumps({"task": args.task, "backend": args.backend, "workers": args.workers,
                      "minutes": round(elapsed / 60.0, 2), "updates": ppo.num_updates,
                      "env_steps": ppo.global_step - started["step"],
                      "start_mib": {key: round(start[key], 1) for key in ("learner", "workers", "total")},
                      "end_mib": {key: round(end[key], 1) for key in ("learner", "workers", "total")},
                      "peak_total_mib": round(peak, 1), "drift_percent": drift(start, end),
                      "lost_episodes": vector_env.lost_episodes}))


if __name__ == "__main__":
    main()
