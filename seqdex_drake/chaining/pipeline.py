"""The bi-directional pipeline (paper Algorithm 1) and its baselines, for any chain of registered sub-tasks.

A pipeline run lives in one directory::

    pipeline.json                 the resolved config and the phases already done (``--resume`` skips them)
    stages/<task>/last.pt         the chain's current policy for each stage (what a chain controller loads)
    phases/<phase>/               each PPO phase's own run directory (TensorBoard, last.pt, best.pt)
    buffers/<a>_to_<b>.npz        forward initialization: pi_a's successful terminal states, rho_b
    transitions/<task>.npz        the previous stage's terminal histories (H = 15) with <task>'s returns
    feasibility/<task>.pt         F^i for stage <task> (predicts its return from the previous stage's history);
                                  <task>_h<H>.pt: the history ablation's F's (seqdex feasibility --history H)
    tstar/<task>.pt               T-STAR's discriminator for the hand-over into <task>
    results.json                  the evaluation

Methods (``--method``): ``seqdex`` (forward initialization, backward fine-tuning with the attention F),
``seqdex_no_temporal`` (the same with the MLP F on the last observation), ``policy_seq`` (forward only; the
fine-tuning budget continues training on the sub-task reward alone), ``tstar`` (fine-tuning with T-STAR's
discriminator reward at the hand-over), ``vchain`` (fine-tuning with the next stage's PPO critic as F),
``scratch`` (one PPO over the whole chain) and ``curriculum`` (one PPO over the whole chain, its start stage
moved from the last back to the first). All share this module's phases, budgets and evaluation, so their
figures are comparable: every method gets ``K * stage_steps + (2M - 1) * (K - 1) * finetune_steps`` PPO steps.
"""

import dataclasses
import json
from pathlib import Path

import numpy as np

from seqdex_drake.atomic import atomic_write
from seqdex_drake.chaining.chain import ChainSpec
from seqdex_drake.chaining.feasibility import LABELS, FeasibilityConfig
from seqdex_drake.tasks.run_config import PRESETS  # Task configs and PPO presets of the stages (PipelineConfig.preset).

METHODS = ("seqdex", "seqdex_no_temporal", "policy_seq", "tstar", "vchain", "scratch", "curriculum")
#: Methods that train one policy per stage and chain them (the others train one policy over the whole chain).
CHAINED_METHODS = METHODS[:5]
#: Evaluation episodes are seeded from here on (training resets use the run seed and its step counts).
EVAL_SEED = 100_000


class PipelineError(ValueError):
    """A pipeline that cannot run as asked (bad method, mismatched run directory, ...); the message says why."""


@dataclasses.dataclass
class PipelineConfig:
    """Budgets and weights of one pipeline run."""

    chain: str = "handover"
    """Name of the chain in ``diagrams/chains.yaml``."""
    method: str = "seqdex"
    """One of :data:`METHODS`."""
    seed: int = 0
    """Seeds PPO, env resets, rollouts and F training."""
    stage_steps: int = 12_000
    """PPO env steps per stage in the forward phase."""
    finetune_steps: int = 6_000
    """PPO env steps per backward fine-tuning step (one per stage but the last, per iteration)."""
    iterations: int = 1
    """M: forward + backward passes (Algorithm 1's outer loop; the forward pass after the first continues each
    stage but the first from its predecessor's new terminal states, for ``finetune_steps``)."""
    transition_episodes: int = 150
    """Chain-prefix rollouts per hand-over, for the terminal buffers and F's (or D's, V's) data."""
    eval_episodes: int = 100
    """Chain episodes of the final evaluation."""
    lambda1: float = 1.0
    """Weight of the sub-task reward while fine-tuning."""
    lambda2: float = 1.0
    """Weight of the transition bonus (F, V or T-STAR's reward) while fine-tuning."""
    bonus_window: int = 1
    """Steps at the end of each episode that receive the bonus (1: the terminal step, as Algorithm 1)."""
    history: int = 10
    """H: observations F reads (0 for the no-temporal method, which uses the last one)."""
    feasibility_epochs: int = 150
    """Epochs of F's regression."""
    threshold_quantile: float = 0.1
    """h is this quantile of the returns of successful executions (``feasibility_label = "return"``)."""
    feasibility_label: str = "return"
    """What every F regresses: "return" (paper eq. 1) or "success" (0/1, the release's label; h = 0.5)."""
    tstar_steps: int = 500
    """Discriminator updates per hand-over (T-STAR)."""
    max_switches: int = 3
    """Switches the evaluation's switcher may make (ours; 0 gives the sequential figure too)."""
    num_envs: int = 2
    """Parallel envs of each PPO phase that starts from scratch (one that continues a checkpoint keeps its
    learner's count)."""
    preset: str = "paper"
    """``paper``: every stage is the task's default MDP trained with the paper's PPO column (pure PPO, for a
    cluster); ``budget``: the task's small-budget variant (``tasks.registry.budget_config``: scripted phases,
    residual on a scripted base) with the budget PPO preset, as ``seqdex train --preset budget`` trains it."""
    init_checkpoints: dict[str, str] = dataclasses.field(default_factory=dict)
    """Per task, a checkpoint (``seqdex train``'s ``last.pt``, same preset) that the stage's forward phase
    continues for ``stage_steps`` more steps instead of starting from scratch: training done before the
    pipeline (e.g. over several sessions) counts as its forward phase."""
    backend: str = "process"
    """Vector env of the sub-task phases: ``process`` (worker processes) or ``serial`` (in this process)."""
    envs_per_worker: int | None = None
    """With the process backend, envs each worker process steps in turn (results do not depend on it); None:
    ceil(num_envs / cores) (``envs.vector.default_envs_per_worker``)."""
    episode_length_cap: int = 0
    """If > 0, every stage's episode is cut to at most this many steps (``--test``)."""
    hidden_sizes: tuple[int, ...] = ()
    """If set, the actor and critic widths of every stage (``--test``); else each task's PPO preset."""
    handoff_failures: bool = False
    """Also hand unsuccessful terminal states to the next stage (and use them as T-STAR's positives when none
    succeeded). Only for ``--test`` runs, whose untrained policies rarely succeed; a real run stops instead."""

    def __post_init__(self):
        if self.method not in METHODS:
            raise PipelineError(f"unknown method {self.method!r}; methods: {', '.join(METHODS)}")
        if self.backend not in ("process", "serial"):
            raise PipelineError(f"backend must be 'process' or 'serial', got {self.backend!r}")
        if self.envs_per_worker is not None and self.envs_per_worker < 1:
            raise PipelineError(f"envs_per_worker must be >= 1, got {self.envs_per_worker}")
        if self.feasibility_label not in LABELS:
            raise PipelineError(f"feasibility_label must be one of {', '.join(LABELS)}, got "
                                f"{self.feasibility_label!r}")
        if self.preset not in PRESETS:
            raise PipelineError(f"unknown preset {self.preset!r}; presets: {', '.join(PRESETS)}")
        self.init_checkpoints = {str(task): str(path) for task, path in dict(self.init_checkpoints).items()}
        self.hidden_sizes = tuple(int(h) for h in self.hidden_sizes)

    @classmethod
    def tiny(cls, **overrides) -> "PipelineConfig":
        """The ``--test`` budget: a few PPO updates, short episodes, a handful of rollouts (minutes on CI)."""
        values = dict(stage_steps=64, finetune_steps=32, transition_episodes=4, eval_episodes=2,
                      feasibility_epochs=3, tstar_steps=5, episode_length_cap=6, hidden_sizes=(32, 32),
                      backend="serial", handoff_failures=True)
        return cls(**{**values, **overrides})

    def feasibility_config(self) -> FeasibilityConfig:
        temporal = self.method == "seqdex"
        return FeasibilityConfig(history=self.history if temporal else 0, temporal=temporal,
                                 epochs=self.feasibility_epochs, seed=self.seed, label=self.feasibility_label)

    def to_dict(self) -> dict:
        data = dataclasses.asdict(self)
        data["hidden_sizes"] = list(self.hidden_sizes)
        data["init_checkpoints"] = dict(self.init_checkpoints)
        return data


def pipeline_budget(config: PipelineConfig, stages: int) -> int:
    """PPO env steps every method gets for a chain of ``stages`` sub-tasks: the first forward pass, then per
    pass one fine-tuning of each stage but the last, and per pass after the first one more forward training of
    each stage but the first."""
    return (stages * config.stage_steps
            + (2 * config.iterations - 1) * (stages - 1) * config.finetune_steps)


#: Config fields that set how work is spread over processes, not what is computed: not compared on resume.
LAYOUT_KEYS = ("envs_per_worker",)


class RunDirectory:
    """The files of one pipeline run and its record of finished phases (written atomically)."""

    def __init__(self, root: str | Path, config: PipelineConfig, chain: ChainSpec, resume: bool):
        self.root = Path(root)
        self.record_path = self.root / "pipeline.json"
        record = {"config": config.to_dict(), "stages": chain.stages, "done": {}}
        if resume:
            if not self.record_path.is_file():
                raise PipelineError(f"--resume: {self.record_path} does not exist; start the run without --resume")
            saved = json.loads(self.record_path.read_text())
            for key, value in PipelineConfig().to_dict().items():  # Fields added since the run started: their
                saved["config"].setdefault(key, value)             # defaults are what it ran with.
            # How the work is spread over processes changes no result: a run may resume with another layout.
            saved["config"].update({k: record["config"][k] for k in LAYOUT_KEYS})
            if saved["config"] != record["config"] or saved["stages"] != record["stages"]:
                changed = sorted(k for k in record["config"] if saved["config"].get(k) != record["config"][k])
                raise PipelineError(f"--resume: {self.root} was started with another configuration (differs in: "
                                    f"{', '.join(changed) or 'stages'}); resume with the same flags")
            record = saved
        elif self.record_path.exists():
            raise PipelineError(f"{self.root} already holds a pipeline run; continue it with --resume or pick "
                                f"another --run-dir")
        self.record = record
        self.root.mkdir(parents=True, exist_ok=True)
        self.save()

    def save(self) -> None:
        """Writes the record (atomically)."""
        data = (json.dumps(self.record, indent=2) + "\n").encode()
        atomic_write(self.record_path, lambda file: file.write(data))

    def done(self, phase: str):
        """The saved outcome of ``phase`` (None if it has not finished)."""
        return self.record["done"].get(phase)

    def finish(self, phase: str, outcome) -> None:
        self.record["done"][phase] = outcome
        self.save()

    def phase_dir(self, phase: str) -> Path:
        return self.root / "phases" / phase

    def policy(self, task: str) -> Path:
        return self.root / "stages" / task / "last.pt"

    def publish_policy(self, task: str, checkpoint: Path) -> None:
        """Makes ``checkpoint`` the chain's policy for ``task`` (an atomic copy)."""
        data = Path(checkpoint).read_bytes()
        atomic_write(self.policy(task), lambda file: file.write(data))

    def buffer(self, source: str, target: str) -> Path:
        return self.root / "buffers" / f"{source}_to_{target}.npz"

    def feasibility(self, task: str) -> Path:
        return self.root / "feasibility" / f"{task}.pt"

    def transitions(self, task: str) -> Path:
        return self.root / "transitions" / f"{task}.npz"

    def tstar(self, task: str) -> Path:
        return self.root / "tstar" / f"{task}.pt"

    def write_results(self, results: dict) -> Path:
        path = self.root / "results.json"
        data = (json.dumps(results, indent=2, default=_plain) + "\n").encode()
        atomic_write(path, lambda file: file.write(data))
        return path


def _plain(value):
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
