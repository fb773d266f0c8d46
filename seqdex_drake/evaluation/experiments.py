"""``seqdex evaluate``'s experiments: success per object (paper Table 1 / 2), the switching ablation (Fig. 5a:
at most 0 / 1 / 2 / 3 feasibility switches), the history ablation (H = 0 / 5 / 10 / 15, from the run's
``feasibility/<task>_h<H>.pt`` files) and the feasibility pose scatter.

Every episode is one object: a block of a type (1-5 trained, 6-8 unseen) from a cached pile to a sampled
stud-aligned goal on the baseplate, or a tool (hammer trained; spatula, spoon unseen) from the table to its
flipped pose. Episode records go to ``episodes.jsonl`` in the output directory; ``resume`` skips the
episodes already recorded there.
"""

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
from pydrake.math import RollPitchYaw

from seqdex_drake.evaluation.plots import write_pose_scatter
from seqdex_drake.evaluation.runner import ChainRunner, RunConfig
from seqdex_drake.evaluation.tables import seed_rates, write_table
from seqdex_drake.manual import ManualStep, goal_vector
from seqdex_drake.modeling.blocks import BLOCK_SPECS
from seqdex_drake.modeling.tools import TOOL_SPECS

SWITCH_SETTINGS = (0, 1, 2, 3)
HISTORY_SETTINGS = (0, 5, 10, 15)
#: The transition whose feasibility scores the scatter shows (paper: Orient -> Grasp; tools: -> Reorient).
SCATTER_STAGE = {"building_blocks": "grasp", "tool_positioning": "tool_reorient"}


@dataclasses.dataclass
class EvalConfig:
    family: str = "building_blocks"
    run_dir: str = "runs/chain"
    out_dir: str = "runs/chain/evaluation"
    episodes: int = 10
    """Episodes per object and seed."""
    seeds: tuple[int, ...] = (0, 1, 2)
    max_switches: int = 3
    stage_steps: tuple[int, ...] | None = None
    """Per-stage budgets (None: each task's episode length)."""
    time_limit: float | None = None
    """Simulated seconds per episode (None: the runner's budget-based limit)."""
    ablation_objects: tuple | None = None
    """Objects the ablations run on (None: all)."""
    untrained_hidden_sizes: tuple[int, ...] | None = None
    resume: bool = False


def objects_of(family: str) -> list[tuple]:
    """(key, label, trained) per object of the family."""
    if family == "building_blocks":
        return [(t, f"Block {t}", BLOCK_SPECS[t].split == "trained") for t in sorted(BLOCK_SPECS)]
    return [(k, name, k == 0) for k, name in enumerate(TOOL_SPECS)]


def sample_goal(block_type: int, rng: np.random.Generator) -> np.ndarray:
    """A stud-aligned goal on the baseplate within the arm's comfortable reach (cells i 3-8, j 8-11), yaw 0/90."""
    yaw = float(rng.choice([0.0, 90.0]))
    nx, ny = BLOCK_SPECS[block_type].cells
    span = (ny, nx) if yaw else (nx, ny)
    cell = [int(rng.integers(3, 9 - span[0] + 1)), int(rng.integers(8, 12 - span[1] + 1))]
    return goal_vector(ManualStep(block_type=block_type, cell=cell, level=0, yaw_deg=yaw))


class Evaluation:
    """Runs the experiments of :class:`EvalConfig`, writing tables and plots into ``out_dir``."""

    def __init__(self, config: EvalConfig, progress=None):
        self.config = config
        self.out = Path(config.out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.records_path = self.out / "episodes.jsonl"
        self.records: list[dict] = []
        if config.resume and self.records_path.is_file():
            self.records = [json.loads(line) for line in self.records_path.read_text().splitlines() if line]
        elif self.records_path.exists():
            self.records_path.unlink()
        self.progress = progress
        self.scatter_rpy: list[np.ndarray] = []
        self.scatter_c: list[float] = []
        self.notes: list[str] = []

    def _done(self, key: dict) -> dict | None:
        for record in self.records:
            if all(record.get(k) == v for k, v in key.items()):
                return record
        return None

    def _runner(self, **overrides) -> ChainRunner:
        c = self.config
        settings = dict(family=c.family, run_dir=c.run_dir, max_switches=c.max_switches, stage_steps=c.stage_steps,
                        seed=c.seeds[0], untrained_hidden_sizes=c.untrained_hidden_sizes)
        settings.update(overrides)
        return ChainRunner(RunConfig(**settings))

    def episodes(self, experiment: str, setting, objects, runner_factory, scatter: bool = False) -> list[dict]:
        """Runs (or reads back) every episode of one experiment setting; returns their records."""
        out, runner = [], None
        for seed in self.config.seeds:
            for key, _, _ in objects:
                for episode in range(self.config.episodes):
                    tag = dict(experiment=experiment, setting=setting, seed=seed, object=key, episode=episode)
                    record = self._done(tag)
                    if record is None:
                        runner = runner or runner_factory()
                        record = {**tag, **self._episode(runner, key, seed, episode, scatter)}
                        self.records.append(record)
                        with self.records_path.open("a") as stream:
                            stream.write(json.dumps(record) + "\n")
                    out.append(record)
                    if self.progress is not None:
                        self.progress.update(1)
        return out

    def _episode(self, runner: ChainRunner, key, seed: int, episode: int, scatter: bool) -> dict:
        rng = np.random.default_rng([seed, int(key), episode])
        if self.config.family == "building_blocks":
            runner.restore_pile(int(rng.integers(1 << 30)))
            runner.start_block(int(key), sample_goal(int(key), rng), reset_robot=True)
        else:
            runner.start_tool(int(key), rng)
        stage = runner.tasks.index(SCATTER_STAGE[self.config.family])

        def record(r: ChainRunner) -> bool:
            c = float(r.chain_output("feasibility_scores")[stage])
            if np.isfinite(c):
                self.scatter_rpy.append(RollPitchYaw(r.object_pose().rotation()).vector())
                self.scatter_c.append(c)
            return True

        limit = self.config.time_limit or runner.episode_limit()
        outcome = runner.run(limit, on_tick=record if scatter else None)
        return {"success": bool(outcome.success), "time": outcome.time, "switches": outcome.switches,
                "last_stage": outcome.last_stage, "position_error": outcome.position_error,
                "rotation_error": outcome.rotation_error}

    # ------------------------------------------------------------------------------------ experiments
    def main_table(self) -> list[Path]:
        objects = objects_of(self.config.family)
        runner = None

        def factory():
            nonlocal runner
            runner = self._runner()
            return runner

        results = self.episodes("main", self.config.max_switches, objects, factory, scatter=True)
        rates = seed_rates(results, objects)
        columns = [label for _, label, _ in objects] + ["trained", "unseen", "all"]
        row = {label: rates[str(key)] for key, label, _ in objects}
        row.update({g: rates[g] for g in ("trained", "unseen", "all")})
        untrained = runner.untrained if runner is not None else []
        notes = [f"{self.config.episodes} episode(s) per object and seed, seeds {list(self.config.seeds)}; "
                 f"success rate mean ± std over seeds",
                 f"untrained stages: {', '.join(untrained)}" if untrained else "every stage trained"]
        table = "table1_building_blocks" if self.config.family == "building_blocks" else "table2_tool_positioning"
        return list(write_table(self.out / table, f"Success rate, {self.config.family} (run {self.config.run_dir})",
                                [f"ours (max {self.config.max_switches} switches)"], columns, [row], notes))

    def _ablation_objects(self):
        objects = objects_of(self.config.family)
        keep = self.config.ablation_objects
        return objects if keep is None else [o for o in objects if o[0] in keep]

    def switching_ablation(self) -> list[Path]:
        objects = self._ablation_objects()
        rows = []
        for k in SWITCH_SETTINGS:
            results = self.episodes("switching", k, objects, lambda k=k: self._runner(max_switches=k))
            rates = seed_rates(results, objects)
            rows.append({g: rates[g] for g in ("trained", "unseen", "all")})
        notes = [f"objects: {', '.join(label for _, label, _ in objects)}; {self.config.episodes} episode(s) per "
                 f"object and seed, seeds {list(self.config.seeds)}",
                 "stages without a feasibility function follow the sequential rule (step budgets), so without F "
                 "files every row is the same policy sequence"]
        return list(write_table(self.out / "ablation_switching", "Switching ablation (paper Fig. 5a)",
                                [f"max {k} switches" for k in SWITCH_SETTINGS], ["trained", "unseen", "all"], rows,
                                notes))

    def history_ablation(self) -> list[Path]:
        objects = self._ablation_objects()
        run_dir = Path(self.config.run_dir)
        tasks = ChainTasks(self.config.family)
        rows, names, notes = [], [], []
        for h in HISTORY_SETTINGS:
            missing = [run_dir / "feasibility" / f"{t}_h{h}.pt" for t in tasks[1:]]
            missing = [str(p) for p in missing if not p.is_file()]
            names.append(f"H = {h}")
            if missing:
                rows.append({})
                notes.append(f"H = {h} skipped: missing {', '.join(missing)} (train F with history {h})")
                continue
            results = self.episodes("history", h, objects, lambda h=h: self._runner(history=h))
            rates = seed_rates(results, objects)
            rows.append({g: rates[g] for g in ("trained", "unseen", "all")})
        return list(write_table(self.out / "ablation_history", "History ablation (H steps of F's input)", names,
                                ["trained", "unseen", "all"], rows, notes))

    def scatter(self) -> Path:
        stage = SCATTER_STAGE[self.config.family]
        tasks = ChainTasks(self.config.family)
        previous = tasks[tasks.index(stage) - 1]
        note = (f"no scores: {Path(self.config.run_dir) / 'feasibility' / (stage + '.pt')} is missing"
                if not self.scatter_c else "")
        return write_pose_scatter(self.out / "feasibility_pose_scatter.png", np.array(self.scatter_rpy),
                                  np.array(self.scatter_c), f"Feasibility of {previous} -> {stage}: object "
                                  f"orientation at scored ticks", note)


def ChainTasks(family: str) -> list[str]:
    from seqdex_drake.chaining.chain import LoadChain

    return list(LoadChain(family).stages)


def total_episodes(config: EvalConfig, history_available: int) -> int:
    per_setting = len(config.seeds) * config.episodes
    main = per_setting * len(objects_of(config.family))
    ablation_objects = len(objects_of(config.family)) if config.ablation_objects is None else \
        len(config.ablation_objects)
    return main + per_setting * ablation_objects * (len(SWITCH_SETTINGS) + history_available)


def history_available(config: EvalConfig) -> int:
    tasks = ChainTasks(config.family)
    return sum(all((Path(config.run_dir) / "feasibility" / f"{t}_h{h}.pt").is_file() for t in tasks[1:])
               for h in HISTORY_SETTINGS)


class CounterBar:
    """A plain stderr counter when tqdm is unavailable."""

    def __init__(self, total: int, desc: str):
        self.total, self.count, self.desc = total, 0, desc

    def update(self, n: int = 1) -> None:
        self.count += n
        print(f"\r{self.desc}: {self.count}/{self.total} episodes", end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        print(file=sys.stderr)


def progress_bar(total: int, desc: str):
    try:
        from tqdm import tqdm
    except ImportError:
        return CounterBar(total, desc)
    return tqdm(total=total, desc=desc, unit="episode", file=sys.stderr)
