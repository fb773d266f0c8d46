"""Ray versus process vector env: env steps/s of the grasp sub-task with 2 workers on each backend.

Both backends are built once (Ray: a local loopback-only instance started by the env), reset with seed 0, warmed
up, then timed alternately ``--repeats`` times for ``--steps`` vector steps of zero actions each (automatic resets
included); steps/s counts env steps (workers x vector steps) and the best of each backend is kept, since other
processes may load the machine. The last line is one JSON object; ``ray_over_process`` is the Ray rate over the
process rate (goal >= 0.9).

    python benchmarks/ray_throughput.py [--task grasp] [--workers 2] [--steps 300] [--repeats 3] [--test]
"""

import argparse
import json
import time

import numpy as np

from seqdex_drake.envs.factory import make_vector_env

WARMUP_STEPS = 10


def _time(vector_env, steps: int) -> float:
    """Env steps per second over ``steps`` vector steps of zero actions."""
    actions = np.zeros(vector_env.action_space.shape)
    start = time.perf_counter()
    for _ in range(steps):
        vector_env.step(actions)
    return steps * len(vector_env) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="grasp")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--steps", type=int, default=300, help="vector steps per timed run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--test", action="store_true", help="a few steps, one repeat")
    args = parser.parse_args()
    if args.test:
        args.steps, args.repeats = 10, 1
    envs = {backend: make_vector_env(args.task, args.workers, seed=0, backend=backend)
            for backend in ("process", "ray")}
    rates = {backend: [] for backend in envs}
    try:
        for vector_env in envs.values():
            vector_env.reset()
            _time(vector_env, WARMUP_STEPS)
        for repeat in range(args.repeats):
            for backend, vector_env in envs.items():
                rates[backend].append(_time(vector_env, args.steps))
                print(f"repeat {repeat}: {backend:7s} {rates[backend][-1]:7.1f} env steps/s")
    finally:
        for vector_env in envs.values():
            vector_env.close()
    best = {backend: max(values) for backend, values in rates.items()}
    print(json.dumps({"task": args.task, "workers": args.workers, "steps": args.steps, "repeats": args.repeats,
                      "process_steps_per_s": round(best["process"], 1), "ray_steps_per_s": round(best["ray"], 1),
                      "ray_over_process": round(best["ray"] / best["process"], 3)}))


if __name__ == "__main__":
    main()
