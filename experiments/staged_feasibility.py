"""F^grasp for the five-stage chain, fitted on the hand-over it scores there: Orient on the staging area, then Grasp.

The switcher scores F^grasp on Orient's observations to decide, during and at the end of Orient, whether to go on
to Grasp (c > 1) or to restart. The shipped F^grasp was fitted for the four-stage chain, on Orient's hand-overs
inside the pile; with the retrieve in the chain, Orient stands blocks up on the staging area instead, and that F
scored them near 0.05 whatever Orient did, so every end of Orient restarted the chain. This refits it where the
chain now runs:

* ``collect``: episode ``e`` (seeded ``--seed + e``) runs the shipped Orient from its own reset on the staging area
  (``--reset-region staging``: one block alone on the clear table in a resting pose, as the retrieve hands it
  over), then the shipped Grasp from Orient's final state (entered as the chain enters it: the open hand back over
  the block, :class:`Approached`), and records Orient's last 15 observations with Grasp's
  return and success (:func:`~seqdex_drake.chaining.rollouts.collect_transitions`, as ``seqdex feasibility``
  collects); ``--intermediate`` more episodes hand over after a random number of Orient's steps, because the
  switcher scores F on every tick of Orient.
* ``fit``: F (attention over H = 10, the success label as the release's, h = 0.5; the shipped F's architecture and
  epochs) on the collected files, with its out-of-fold AUC (``--folds``), and the shipped F^grasp's AUC and mean
  score on the same hand-overs beside it. ``--ship`` puts the new F in ``checkpoints/building_blocks/`` and records
  the command and figures in its manifest entry.

    python experiments/staged_feasibility.py collect --seed 0 --episodes 150 --intermediate 75 --out runs/staged_f/a.npz
    python experiments/staged_feasibility.py collect --seed 100000 --episodes 150 --intermediate 75 \\
        --out runs/staged_f/b.npz
    python experiments/staged_feasibility.py fit runs/staged_f/a.npz runs/staged_f/b.npz --folds 5 \\
        --out runs/staged_f/grasp.pt [--ship]
    python experiments/staged_feasibility.py collect --test --out /tmp/t.npz   # 2 episodes cut short, for CI

No evaluation pile or seed is used: the resets are the Orient env's own, on the staging area.
"""

import argparse
import dataclasses
import hashlib
import io
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "checkpoints" / "building_blocks"
SOURCE, TARGET = "orient", "grasp"
#: The shipped F's settings (its pipeline's: H = 10, 150 epochs; the transitions keep 15 steps as the pipeline's).
HISTORY, EPOCHS, SAVED_HISTORY = 10, 150, 15


class Approached:
    """Grasp's env, entered as the chain enters Grasp: from a hand-over state, the approach first brings the open
    hand back over the block (``ChainParams.approach_stages``), here by placing it there, as Grasp's own resets do
    (the open hand ``hover_height`` over the block, at rest). Everything else is the env's."""

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def reset(self, *, seed=None, options=None):
        from seqdex_drake.robots.allegro import ALLEGRO_OPEN_Q

        observation, info = self.env.reset(seed=seed, options=options)
        if options and options.get("initial_state") is not None:
            env = self.env
            env.set_robot(env.hover_arm(env.object_position()), ALLEGRO_OPEN_Q)
            env.simulator.Initialize()
            env.refresh_sampled_outputs()
            observation = env.observation()
        return observation, info


def stage_envs_and_policies(test: bool):
    """The shipped Orient (its resets on the staging area) and Grasp: their envs and deterministic policies."""
    from seqdex_drake.chaining.chain import LoadChain
    from seqdex_drake.chaining.chain_files import observation_sizes
    from seqdex_drake.chaining.shipped import load_shipped_chain
    from seqdex_drake.envs.subtask_env import make_env
    from seqdex_drake.rl.policy_loading import load_policy

    tasks = list(LoadChain("building_blocks").stages)
    shipped = load_shipped_chain(SHIPPED, "building_blocks", tasks, observation_sizes())
    envs, policies = [], []
    for task in (SOURCE, TARGET):
        config = shipped.configs[tasks.index(task)]
        if task == SOURCE:
            config = dataclasses.replace(config, reset_region="staging")
        if test:
            config = dataclasses.replace(config, episode_length=5)
        envs.append(make_env(task, config) if task == SOURCE else Approached(make_env(task, config)))
        policies.append(load_policy(shipped.policies[tasks.index(task)], deterministic=True, task=task))
    return envs, policies


def collect(args) -> int:
    from seqdex_drake.atomic import atomic_write
    from seqdex_drake.chaining.rollouts import collect_transitions

    start = time.perf_counter()
    envs, policies = stage_envs_and_policies(args.test)
    episodes, intermediate = (2, 0) if args.test else (args.episodes, args.intermediate)
    steps = [0]

    def counted(policy):  # One call per env step.
        def act(observation):
            steps[0] += 1
            return policy(observation)
        return act

    data = collect_transitions(envs, [counted(policy) for policy in policies], 1, episodes, args.seed,
                               history=SAVED_HISTORY, intermediate=intermediate)
    arrays = {"histories": data.histories, "returns": data.returns, "successes": data.successes,
              "source_successes": data.source_successes, "seed": np.array(args.seed),
              "episodes": np.array(episodes), "intermediate": np.array(intermediate),
              "wall_seconds": np.array(time.perf_counter() - start), "env_steps": np.array(steps[0])}
    payload = io.BytesIO()
    np.savez(payload, **arrays)
    atomic_write(args.out, lambda file: file.write(payload.getvalue()))
    print(f"staged_feasibility collect: {len(data.returns)} hand-overs (Orient stood up {data.source_successes.sum()}"
          f", Grasp succeeded from {data.successes.sum()}) in {time.perf_counter() - start:.0f} s; wrote {args.out}")
    return 0


def load(paths: list[str]) -> dict:
    parts = []
    for path in paths:
        with np.load(path) as file:
            parts.append({key: file[key] for key in ("histories", "returns", "successes", "source_successes")})
    return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}


def shipped_scores(data: dict) -> np.ndarray:
    """The shipped F^grasp's c on each hand-over (its last H observations)."""
    from seqdex_drake.chaining.feasibility import score
    from seqdex_drake.chaining.feasibility_io import load_feasibility

    f = load_feasibility(SHIPPED / "feasibility" / f"{TARGET}.pt")
    length = int(f.config.input_length)
    return np.array([score(f.model, history[-length:], f.threshold) for history in data["histories"]])


def fit(args) -> int:
    from seqdex_drake.chaining.feasibility import FeasibilityConfig
    from seqdex_drake.chaining.feasibility_fit import fit_and_save
    from seqdex_drake.chaining.feasibility_metrics import roc_auc

    data = load(args.files)
    if data["successes"].all() or not data["successes"].any():
        print(f"staged_feasibility fit: Grasp succeeded from {data['successes'].sum()} of {len(data['successes'])} "
              f"hand-overs; F needs successes and failures: collect more", file=sys.stderr)
        return 1
    config = FeasibilityConfig(history=HISTORY, epochs=EPOCHS, label="success", seed=args.seed)
    outcome = fit_and_save(data, config, 0.1, args.out, SOURCE, TARGET, args.folds)
    old = shipped_scores(data)
    outcome.update({"hand_overs": int(len(data["successes"])), "grasp_successes": int(data["successes"].sum()),
                    "orient_successes": int(data["source_successes"].sum()),
                    "shipped_f_auc": float(roc_auc(old, data["successes"])),
                    "shipped_f_mean_c": float(old.mean()),
                    "shipped_f_above_1": int((old > 1).sum())})
    print(json.dumps(outcome, indent=1))
    if args.ship:
        ship(Path(args.out), outcome, args)
    return 0


def ship(path: Path, outcome: dict, args) -> None:
    """Copies F into the shipped folder and records it (file hash, how it was fitted) in the manifest."""
    from seqdex_drake.atomic import atomic_write

    manifest_path = SHIPPED / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    target = SHIPPED / "feasibility" / f"{TARGET}.pt"
    shutil.copyfile(path, target)
    manifest["feasibility"][TARGET] = {
        "file": f"feasibility/{TARGET}.pt", "sha256": hashlib.sha256(target.read_bytes()).hexdigest(),
        "fitted": {"by": "experiments/staged_feasibility.py (Orient's hand-overs on the staging area)",
                   "files": [str(Path(f)) for f in args.files], **outcome}}
    atomic_write(manifest_path, lambda file: file.write((json.dumps(manifest, indent=1) + "\n").encode()))
    print(f"staged_feasibility: shipped {target}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    c = commands.add_parser("collect", help="Orient on the staging area, then Grasp: the hand-overs")
    c.add_argument("--seed", type=int, default=0, help="episode e is seeded seed + e (default 0)")
    c.add_argument("--episodes", type=int, default=150, help="hand-overs at Orient's end (default 150)")
    c.add_argument("--intermediate", type=int, default=75, help="hand-overs during Orient (default 75)")
    c.add_argument("--out", required=True, help="the transitions file (.npz)")
    c.add_argument("--test", action="store_true", help="2 episodes of 5 steps, for CI")
    f = commands.add_parser("fit", help="fit F^grasp on collected hand-overs")
    f.add_argument("files", nargs="+", help="transitions files written by collect")
    f.add_argument("--folds", type=int, default=5, help="out-of-fold AUC over K folds (default 5; 0: none)")
    f.add_argument("--seed", type=int, default=0, help="F's training seed (default 0)")
    f.add_argument("--out", required=True, help="the F file to write (.pt)")
    f.add_argument("--ship", action="store_true", help="also put it in checkpoints/building_blocks/ (manifest)")
    args = parser.parse_args(argv)
    from seqdex_drake.user_input import InputError, check_creatable

    try:
        check_creatable(args.out, "--out")
        if args.command == "collect":
            if args.episodes < 1 or args.intermediate < 0:
                raise InputError(f"--episodes must be >= 1 and --intermediate >= 0, got {args.episodes} and "
                                 f"{args.intermediate}")
        else:
            missing = [name for name in args.files if not Path(name).is_file()]
            if missing:
                raise InputError(f"no transitions file {', '.join(missing)}; write it with the collect command")
            if args.folds < 0 or args.folds == 1:
                raise InputError(f"--folds takes 0 (none) or K >= 2, got {args.folds}")
    except InputError as error:
        print(f"staged_feasibility: {error}", file=sys.stderr)
        return 2
    return collect(args) if args.command == "collect" else fit(args)


if __name__ == "__main__":
    sys.exit(main())
