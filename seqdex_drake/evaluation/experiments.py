"""``seqdex evaluate``'s experiments: success per object (paper Table 1 / 2), the switching ablation (Fig. 5a:
at most 0 / 1 / 2 / 3 feasibility switches), the history ablation (H = 0 / 5 / 10 / 15, from the run's
``feasibility/<task>_h<H>.pt`` files) and the feasibility pose scatter.

Every episode is one object: a block of a type (1-5 trained, 6-8 unseen) from a cached pile to a sampled
stud-aligned goal on the baseplate, or a tool (hammer trained; spatula, spoon unseen) from the table to its
flipped pose. ``EvalConfig.objects`` restricts every experiment to some objects. Episode records go to
``episodes.jsonl`` in the output directory; ``resume`` skips the episodes already recorded there. With
``EvalConfig.workers`` > 1 the episodes run in worker processes (``evaluation/parallel.py``), seeds split over them;
every episode is seeded by (seed, object, episode) and the runner by the first seed, so the records are the same.
"""

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from seqdex_drake import numerics
from seqdex_drake.chaining.chain import LoadChain
from seqdex_drake.evaluation.episodes import (  # noqa: F401
    SCATTER_STAGE,
    handover_notes,
    run_config,
    run_episode,
    sample_goal,
)
from seqdex_drake.evaluation.parallel import WorkerPool
from seqdex_drake.evaluation.plots import write_pose_scatter
from seqdex_drake.evaluation.runner import ChainRunner
from seqdex_drake.evaluation.tables import seed_rates, write_table
from seqdex_drake.modeling.catalog import objects_of

SWITCH_SETTINGS = (0, 1, 2, 3)
HISTORY_SETTINGS = (0, 5, 10, 15)


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
    """Objects the ablations run on, of ``objects`` (None: all of them)."""
    untrained_hidden_sizes: tuple[int, ...] | None = None
    resume: bool = False
    objects: tuple | None = None
    """Objects the main table and the ablations run on (tool indices, block types; None: all)."""
    label: str = ""
    """The main table's row name (default: "ours (max N switches)")."""
    workers: int = 1
    """Processes running the episodes (seeds round-robin over at most ``len(seeds)`` of them)."""
    chain: str = ""
    """The chain to run (``diagrams/chains.yaml``; ``RunConfig.chain``); "": the family's own."""
    trigger: str = ""
    """The switcher's trigger (``RunConfig.trigger``); "": the family's."""


def selected_objects(config: EvalConfig, subset: tuple | None = None) -> list[tuple]:
    """:func:`objects_of` the family, restricted to ``config.objects`` and then to ``subset`` (None: all)."""
    objects = objects_of(config.family)
    for keep in (config.objects, subset):
        if keep is not None:
            objects = [o for o in objects if o[0] in keep]
    return objects


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
        self._index = {_key(record): record for record in self.records}
        self.progress = progress
        self.scatter_rpy: list[np.ndarray] = []
        self.scatter_c: list[float] = []
        self.notes: list[str] = []
        self.untrained: list[str] | None = None
        """The untrained stages of the last runner built (None: no episode ran)."""
        self._pool = None  # The worker processes (config.workers > 1), started at the first parallel setting.

    def close(self) -> None:
        """Stops the worker processes, if any."""
        if self._pool is not None:
            pool, self._pool = self._pool, None
            pool.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _add(self, record: dict) -> None:
        """Keeps a new episode record and appends it to ``episodes.jsonl`` (only this process writes there)."""
        self.records.append(record)
        self._index[_key(record)] = record
        with self.records_path.open("a") as stream:
            stream.write(json.dumps(record) + "\n")
        if self.progress is not None:
            self.progress.update(1)

    def episodes(self, experiment: str, setting, objects, overrides: dict | None = None,
                 scatter: bool = False) -> list[dict]:
        """Runs (or reads back) every episode of one experiment setting (the runner built with ``overrides`` of
        :func:`run_config`), in ``config.workers`` processes; returns their records, by seed, object, episode."""
        overrides = overrides or {}
        tags = [dict(experiment=experiment, setting=setting, seed=seed, object=key, episode=episode)
                for seed in self.config.seeds for key, _, _ in objects for episode in range(self.config.episodes)]
        pending = [tag for tag in tags if _key(tag) not in self._index]
        if self.progress is not None and len(tags) > len(pending):
            self.progress.update(len(tags) - len(pending))
        if pending and self.config.workers > 1 and len({tag["seed"] for tag in pending}) > 1:
            points = {}

            def on_episode(record: dict, rpy: list, scores: list) -> None:
                self._add(record)
                points[_key(record)] = (rpy, scores)

            self._pool = self._pool or WorkerPool(self.config)
            try:
                self.untrained = self._pool.run(pending, overrides, scatter, on_episode)
            except BaseException:
                self._pool = None  # A failed run has stopped the workers.
                raise
            for tag in pending:  # Scatter points in the single-process order.
                rpy, scores = points[_key(tag)]
                self.scatter_rpy += rpy
                self.scatter_c += scores
        elif pending:
            runner = ChainRunner(run_config(self.config, **overrides))
            self.untrained = list(runner.untrained)
            for tag in pending:
                result, rpy, scores = run_episode(runner, self.config, tag["object"], tag["seed"], tag["episode"],
                                                  scatter)
                self.scatter_rpy += rpy
                self.scatter_c += scores
                self._add({**tag, **result})
        return [self._index[_key(tag)] for tag in tags]

    # ------------------------------------------------------------------------------------ experiments
    def main_table(self) -> list[Path]:
        objects = selected_objects(self.config)
        self.untrained = None
        results = self.episodes("main", self.config.max_switches, objects, scatter=True)
        rates = seed_rates(results, objects)
        columns = [label for _, label, _ in objects] + ["trained", "unseen", "all"]
        row = {label: rates[str(key)] for key, label, _ in objects}
        row.update({g: rates[g] for g in ("trained", "unseen", "all")})
        untrained = self.untrained or []
        notes = [f"{self.config.episodes} episode(s) per object and seed, seeds {list(self.config.seeds)}; "
                 f"success rate mean ± std over seeds",
                 f"untrained stages: {', '.join(untrained)}" if untrained else "every stage trained",
                 *handover_notes(self.config.family, results),
                 f"made on: {numerics.machine()} (exact replays need the same)"]
        table = "table1_building_blocks" if self.config.family == "building_blocks" else "table2_tool_positioning"
        return list(write_table(self.out / table, f"Success rate, {self.config.family} (run {self.config.run_dir})",
                                [self.config.label or f"ours (max {self.config.max_switches} switches)"], columns,
                                [row], notes))

    def _ablation_objects(self):
        return selected_objects(self.config, self.config.ablation_objects)

    def switching_ablation(self) -> list[Path]:
        objects = self._ablation_objects()
        rows = []
        for k in SWITCH_SETTINGS:
            results = self.episodes("switching", k, objects, dict(max_switches=k))
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
        tasks = ChainTasks(self.config.family, self.config.chain)
        rows, names, notes = [], [], []
        for h in HISTORY_SETTINGS:
            missing = [run_dir / "feasibility" / f"{t}_h{h}.pt" for t in tasks[1:]]
            missing = [str(p) for p in missing if not p.is_file()]
            names.append(f"H = {h}")
            if missing:
                rows.append({})
                notes.append(f"H = {h} skipped: missing {', '.join(missing)} (train F with history {h})")
                continue
            results = self.episodes("history", h, objects, dict(history=h))
            rates = seed_rates(results, objects)
            rows.append({g: rates[g] for g in ("trained", "unseen", "all")})
        return list(write_table(self.out / "ablation_history", "History ablation (H steps of F's input)", names,
                                ["trained", "unseen", "all"], rows, notes))

    def scatter(self) -> Path:
        stage = SCATTER_STAGE[self.config.family]
        tasks = ChainTasks(self.config.family, self.config.chain)
        previous = tasks[tasks.index(stage) - 1]
        note = (f"no scores: {Path(self.config.run_dir) / 'feasibility' / (stage + '.pt')} is missing"
                if not self.scatter_c else "")
        return write_pose_scatter(self.out / "feasibility_pose_scatter.png", np.array(self.scatter_rpy),
                                  np.array(self.scatter_c), f"Feasibility of {previous} -> {stage}: object "
                                  f"orientation at scored ticks", note)


def ChainTasks(family: str, chain: str = "") -> list[str]:
    """The stages of ``chain`` (``diagrams/chains.yaml``), "": of the family's own chain."""
    return list(LoadChain(chain or family).stages)


def _key(record: dict) -> tuple:
    return tuple(record[k] for k in ("experiment", "setting", "seed", "object", "episode"))


def total_episodes(config: EvalConfig, history_available: int, ablations: bool = True) -> int:
    """Episodes of the main table (and, if ``ablations``, of the switching and ``history_available`` history
    settings)."""
    per_setting = len(config.seeds) * config.episodes
    total = per_setting * len(selected_objects(config))
    if ablations:
        total += per_setting * len(selected_objects(config, config.ablation_objects)) * \
            (len(SWITCH_SETTINGS) + history_available)
    return total


def history_available(config: EvalConfig) -> int:
    tasks = ChainTasks(config.family, config.chain)
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
        from tqdm import tqdm  # Optional here: a plain counter without it.
    except ImportError:
        return CounterBar(total, desc)
    return tqdm(total=total, desc=desc, unit="episode", file=sys.stderr)
