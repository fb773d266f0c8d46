"""Roll a scripted controller out in a sub-task's env and keep its successful episodes as demonstrations.

    python scripts/collect_demos.py --task tool_grasp --episodes 50 --workers 2 --out demos/tool_grasp.npz
    python scripts/collect_demos.py --task tool_grasp --episodes 1 --out /tmp/demo.npz --test

The env is the task's ``--preset`` variant (``budget`` by default, as ``seqdex train``) without its residual base
(the demonstrations hold whole actions), so the demonstrations are in the env ``seqdex train --demos`` trains in.
Only episodes that the env's own success test passes are kept
(``seqdex_drake/rl/demonstrations.py``); train on them with ``seqdex train --task TASK --demos FILE``.
"""

import argparse
import sys
import time
from pathlib import Path

#: Seeds of worker k start at ``--seed + k * WORKER_SEED_STRIDE`` (disjoint for any realistic attempt count).
WORKER_SEED_STRIDE = 100_000


def _controllers() -> dict:
    """Task -> scripted controller class."""
    from seqdex_drake.tasks.scripted.tool_grasp_script import ScriptedToolGrasp

    return {"tool_grasp": ScriptedToolGrasp}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--episodes", type=int, default=50, help="successful episodes to keep (default 50)")
    parser.add_argument("--max-attempts", type=int, help="episodes to try at most (default: 4 x --episodes)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (then +1 per attempt)")
    parser.add_argument("--preset", choices=("budget", "paper"), default="budget")
    parser.add_argument("--out", required=True, help="the demonstration file (.npz)")
    parser.add_argument("--workers", type=int, default=1,
                        help=f"parallel processes, worker k from seed --seed + {WORKER_SEED_STRIDE} k (default 1)")
    parser.add_argument("--test", action="store_true", help="one attempt, for CI")
    args = parser.parse_args(argv)
    controllers = _controllers()
    if args.task not in controllers:
        parser.error(f"no scripted controller for {args.task!r}; have: {', '.join(controllers)}")
    if args.episodes < 1 or args.seed < 0 or args.workers < 1 or (args.max_attempts is not None
                                                                   and args.max_attempts < 1):
        parser.error("--episodes, --workers and --max-attempts must be >= 1, --seed >= 0")
    out = Path(args.out)
    if out.exists() and out.is_dir() or not _writable_parent(out):
        parser.error(f"cannot write {out}: its folder is not writable or it is a directory")
    from seqdex_drake.rl.demonstrations import Demonstrations

    start = time.perf_counter()
    workers = max(1, min(args.workers, args.episodes))
    jobs = [(args.task, args.preset, args.episodes // workers + (k < args.episodes % workers),
             args.seed + k * WORKER_SEED_STRIDE, 1 if args.test else args.max_attempts) for k in range(workers)]
    try:
        if workers == 1:
            parts = [_collect(*jobs[0])]
        else:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
                parts = list(pool.map(_collect, *zip(*jobs, strict=True)))
    except RuntimeError as error:
        print(f"collect_demos: error: {error}", file=sys.stderr)
        return 1
    demos = Demonstrations.concatenate(parts)
    demos.save(out)
    print(f"collect_demos: {demos.num_episodes} successful {args.task} episodes of {demos.attempts} attempts "
          f"({demos.num_episodes / demos.attempts:.2f}), {len(demos)} transitions, "
          f"{time.perf_counter() - start:.0f} s -> {out}")
    return 0


def _collect(task: str, preset: str, episodes: int, seed: int, max_attempts: int | None):
    """One worker's share: ``episodes`` successful episodes from seeds ``seed``, ``seed + 1``, ..."""
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.rl.demonstrations import collect_demonstrations
    from seqdex_drake.tasks.run_config import task_config

    env = make_env(task, task_config(task, False, preset, residual=False))  # Whole actions, not corrections.
    return collect_demonstrations(env, _controllers()[task](), task, episodes, seed, max_attempts)


def _writable_parent(path: Path) -> bool:
    """Whether ``path``'s folder exists (or can be made) and is writable."""
    import os

    parent = path.resolve().parent
    while not parent.exists():
        parent = parent.parent
    return parent.is_dir() and os.access(parent, os.W_OK)


if __name__ == "__main__":
    sys.exit(main())
