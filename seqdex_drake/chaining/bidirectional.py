"""Running a pipeline: forward initialization, backward fine-tuning (paper Algorithm 1), the baselines and the
final evaluation, phase by phase in a :class:`~seqdex_drake.chaining.pipeline.RunDirectory` so that an
interrupted run resumes where it stopped (a PPO phase continues from its own ``last.pt``).

Nothing here knows the sub-tasks: stages come from the chain spec and are built through the task registry.
Nor does it import the env package: the vector envs of the PPO phases come from the
:class:`~seqdex_drake.chaining.stage_envs.EnvKit` the caller passes in (``env_kit``).
"""

import dataclasses
import io
import json
import shutil
import time
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path

import numpy as np
import torch

from seqdex_drake.atomic import atomic_write
from seqdex_drake.chaining.chain import ChainSpec, LoadChain
from seqdex_drake.chaining.feasibility import pad_history
from seqdex_drake.chaining.feasibility_fit import fit_and_save
from seqdex_drake.chaining.feasibility_io import load_feasibility
from seqdex_drake.chaining.pipeline import (
    CHAINED_METHODS,
    EVAL_SEED,
    PipelineConfig,
    PipelineError,
    RunDirectory,
    pipeline_budget,
)
from seqdex_drake.chaining.rollouts import collect_transitions, deterministic_policy, evaluate_chain, run_prefix
from seqdex_drake.chaining.single_policy import run_single_policy
from seqdex_drake.chaining.stage_envs import EnvKit, default_env_kit, pooled_env
from seqdex_drake.chaining.terminal_buffer import TerminalBuffer
from seqdex_drake.chaining.tstar import fit_tstar, tstar_bonus
from seqdex_drake.chaining.wrappers import InitialStateVectorEnv, TransitionBonusVectorEnv
from seqdex_drake.env_state import EnvState, check_handoff
from seqdex_drake.rl.checkpoint import CheckpointError, load_checkpoint
from seqdex_drake.rl.config import PPOConfig
from seqdex_drake.rl.ppo import PPO
from seqdex_drake.tasks.registry import KNOCK_OUTS, budget_config, default_config, is_scripted
from seqdex_drake.tasks.run_config import observation_spec

#: Observations kept per transition (the history ablation goes up to H = 15).
TRANSITION_HISTORY = 15


class Pipeline:
    """One run of ``config.method`` on ``chain`` in ``run_dir``.

    Args:
        chain: the chain (consecutive stages on one station scene, or on scenes a hand-off crosses).
        config: budgets, weights and the method.
        run_dir: the run directory (see :mod:`seqdex_drake.chaining.pipeline`).
        resume: continue a run in ``run_dir`` instead of starting one.
        progress: show PPO progress bars.
        log: where one-line progress messages go.
        env_kit: the env classes of the PPO phases (default:
            :func:`~seqdex_drake.chaining.stage_envs.default_env_kit`, this package's).
    """

    @classmethod
    def open(cls, run_dir, progress: bool = False, log: Callable[[str], None] = print,
             env_kit: EnvKit | None = None) -> "Pipeline":
        """The pipeline run already in ``run_dir`` (its chain and config from ``pipeline.json``)."""
        record_path = Path(run_dir) / "pipeline.json"
        if not record_path.is_file():
            raise PipelineError(f"{run_dir} holds no pipeline run ({record_path.name} is missing); start one with "
                                f"seqdex pipeline --chain <chain> --run-dir {run_dir}")

        record = json.loads(record_path.read_text())
        config = PipelineConfig(**record["config"])
        chain = LoadChain(config.chain)
        if chain.stages != record["stages"]:
            raise PipelineError(f"chain {config.chain!r} now has stages {chain.stages}, the run in {run_dir} was "
                                f"made with {record['stages']}")
        return cls(chain, config, run_dir, resume=True, progress=progress, log=log, env_kit=env_kit)

    def __init__(self, chain: ChainSpec, config: PipelineConfig, run_dir, resume: bool = False,
                 progress: bool = False, log: Callable[[str], None] = print, env_kit: EnvKit | None = None):
        self.chain, self.config, self.progress, self.log = chain, config, progress, log
        self.env_kit = env_kit
        self.stages = chain.stages
        scripted = [task for task in self.stages if is_scripted(task)]
        if scripted:  # Its base acts alone: no PPO phase, no policy checkpoint to hand states from.
            raise PipelineError(f"chain {config.chain!r} has the scripted stage(s) {', '.join(scripted)} "
                                f"(Task.scripted): the pipeline trains chains of learned stages only; train the "
                                f"learned stages with seqdex train (forward initialization: seqdex collect) and "
                                f"ship them with seqdex ship")
        self.task_configs = [self._task_config(task) for task in self.stages]
        self.run = RunDirectory(run_dir, config, chain, resume)
        self._envs = None

    # -------------------------------------------------------------------------------------------- pieces
    def _task_config(self, task: str):
        config = budget_config(task) if self.config.preset == "budget" else default_config(task)
        if self.config.episode_length_cap > 0:
            config = dataclasses.replace(config, episode_length=min(config.episode_length,
                                                                    self.config.episode_length_cap))
        return config

    def _ppo_config(self, task: str) -> PPOConfig:
        overrides = {"seed": self.config.seed, "num_envs": self.config.num_envs}
        if self.config.hidden_sizes:
            overrides.update(actor_hidden_sizes=self.config.hidden_sizes, critic_hidden_sizes=self.config.hidden_sizes)
        if self.config.episode_length_cap > 0:  # Tiny runs: a few short rollouts per update.
            overrides.update(horizon=8, num_minibatches=2)
        residual = bool(self.task_configs[self.stages.index(task)].residual)
        return PPOConfig.for_preset(task, self.config.preset, residual=residual, **overrides)

    def stage_envs(self) -> list:
        """One in-process env per stage (for rollouts and evaluation), built once."""
        if self._envs is None:
            self._envs = [pooled_env(task, config, 0) for task, config in zip(self.stages, self.task_configs,
                                                                              strict=True)]
            for source, target in pairwise(self._envs):  # Hand-offs across scenes: envs/scene_handoff.py
                if source.plant.num_positions() != target.plant.num_positions():
                    check_handoff(source.objects.names, target.objects.names)
        return self._envs

    def require_env_kit(self) -> EnvKit:
        """The env classes of the PPO phases (the ``env_kit`` given, else :func:`default_env_kit`)."""
        return self.env_kit if self.env_kit is not None else default_env_kit()

    def _vector_env(self, index: int, seed: int, num_envs: int):
        task, config = self.stages[index], self.task_configs[index]
        kit = self.require_env_kit()
        if self.config.backend == "process":
            return kit.process_vector_env(task, num_envs, seed=seed, config=config,
                                          envs_per_worker=self.config.envs_per_worker)  # None: one per core.
        return kit.serial_vector_env([lambda slot=slot: pooled_env(task, config, 1 + slot)
                                      for slot in range(num_envs)], seed=seed)

    def policies(self, upto: int | None = None) -> list:
        """The chain's current policies of stages ``0 .. upto`` (default: all), as deterministic callables."""
        stages = self.stages if upto is None else self.stages[:upto + 1]
        return [deterministic_policy(PPO.resume(self.run.policy(task))) for task in stages]

    # ------------------------------------------------------------------------------------------- phases
    def _timed(self, phase: str, work: Callable[[], dict]) -> dict:
        """Runs ``work`` unless ``phase`` is done; records its outcome with its wall-clock time."""
        outcome = self.run.done(phase)
        if outcome is not None:
            return outcome
        start = time.perf_counter()
        outcome = work()
        outcome["seconds"] = time.perf_counter() - start
        self.run.finish(phase, outcome)
        self.log(f"[{self.config.method}] {phase}: " + ", ".join(
            f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in outcome.items()))
        return outcome

    def phase_learner(self, phase: str, steps: int, start_from=None, fresh_episodes: bool = False):
        """The learner and step target of PPO phase ``phase``: an interrupted phase continues from its own
        ``last.pt`` toward its recorded target; a new one starts from ``start_from`` (or from scratch: None is
        returned and the caller builds the learner) and records its target at once, so a kill keeps it.
        ``fresh_episodes``: drop the env state saved in ``start_from`` (a checkpoint of another run, whose envs
        are not this phase's), so the phase starts new episodes."""
        directory = self.run.phase_dir(phase)
        targets = self.run.record.setdefault("targets", {})
        if (directory / "last.pt").is_file() and phase in targets:
            return PPO.resume(directory / "last.pt"), targets[phase]
        ppo = PPO.resume(start_from) if start_from is not None else None
        if ppo is not None and fresh_episodes:
            ppo._saved_env_state = None
        targets[phase] = (0 if ppo is None else ppo.global_step) + steps
        self.run.save()
        return ppo, targets[phase]

    def train_stage(self, phase: str, index: int, steps: int, start_from=None, buffer_path=None,
                    bonus=None, foreign: bool = False) -> dict:
        """PPO on stage ``index`` for ``steps`` env steps (from scratch, or continuing ``start_from``; ``foreign``:
        a checkpoint of another run, see :meth:`phase_learner`), its episodes starting from ``buffer_path``'s
        states if given, its reward shaped by ``bonus`` if given; the result becomes the chain's policy for that
        stage."""
        def work():
            task, directory = self.stages[index], self.run.phase_dir(phase)
            ppo, target = self.phase_learner(phase, steps, start_from, fresh_episodes=foreign)
            seed = self.config.seed + 1000 * index
            num_envs = ppo.config.num_envs if ppo is not None else self._ppo_config(task).num_envs
            env = self._vector_env(index, seed, num_envs)
            try:
                if buffer_path is not None:
                    buffer = TerminalBuffer.load(buffer_path, expected_task=task)
                    env = InitialStateVectorEnv(env, buffer, seed, EnvState,
                                                successful_only=not self.config.handoff_failures)
                if bonus is not None:
                    env = TransitionBonusVectorEnv(env, bonus, self.config.lambda1, self.config.lambda2,
                                                   history=max(self.config.history, 1),
                                                   window=self.config.bonus_window,
                                                   episode_length=self.task_configs[index].episode_length)
                if ppo is None:
                    ppo = PPO.for_env(self._ppo_config(task), env)
                    ppo.obs_spec = observation_spec(task, env.single_observation_space.shape[0]).to_dict()
                metrics = ppo.train(env, directory, total_steps=target, progress=self.progress)
            finally:
                env.close()
            self.run.publish_policy(task, directory / "last.pt")
            return {"steps": steps, "success_rate": float(metrics.get("charts/success_rate", np.nan))}

        return self._timed(phase, work)

    def collect_buffer(self, phase: str, index: int) -> dict:
        """Forward initialization: pi_index's successful terminal states (chain-prefix rollouts) -> rho_{index+1}."""
        def work():
            envs, policies = self.stage_envs(), self.policies(index)
            source, target = self.stages[index], self.stages[index + 1]
            dim = envs[index].observation_space.shape[0]
            buffer = TerminalBuffer(source, target, self.task_configs[index].scenario, observation_spec(source, dim),
                                    max(self.config.history, 1))
            env_steps = 0
            for episode in range(self.config.transition_episodes):
                result = run_prefix(envs, policies, index, self.config.seed + 7919 * (index + 1) + episode)
                buffer.append(result.state, pad_history(result.observations, buffer.history), result.episode_return,
                              result.success)
                env_steps += len(result.observations) - 1
            if not buffer.successes.any() and not self.config.handoff_failures:
                raise RuntimeError(f"no {source} rollout succeeded in {self.config.transition_episodes} episodes, "
                                   f"so {target} has no initial states; give {source} a larger --stage-steps")
            buffer.save(self.run.buffer(source, target))
            return {"episodes": self.config.transition_episodes, "success_rate": float(buffer.successes.mean()),
                    "last_stage_steps": env_steps}

        return self._timed(phase, work)

    def collect_transition_data(self, phase: str, index: int, intermediate: int = 0, knocked_out: int = 0) -> dict:
        """Chain-prefix rollouts into stage ``index``: pi^{index-1}'s terminal histories (H = 15, the longest the
        history ablation uses) with pi^{index}'s returns and successes, saved to ``transitions/<task>.npz``; and
        ``intermediate`` early hand-overs and ``knocked_out`` ones with the object knocked out of the hand
        (:func:`~seqdex_drake.chaining.rollouts.collect_transitions`; ``tasks/registry.KNOCK_OUTS``)."""
        source = self.stages[index - 1]
        if knocked_out and source not in KNOCK_OUTS:
            raise ValueError(f"no knock-out is defined for {source} (have: {', '.join(KNOCK_OUTS)})")

        def work():
            data = collect_transitions(self.stage_envs(), self.policies(index), index,
                                       self.config.transition_episodes, self.config.seed + 104729 * index,
                                       history=max(TRANSITION_HISTORY, self.config.history), intermediate=intermediate,
                                       knocked_out=knocked_out, knock_out=KNOCK_OUTS.get(source))
            arrays = {"histories": data.histories, "returns": data.returns, "successes": data.successes,
                      "source_successes": data.source_successes}
            payload = io.BytesIO()
            np.savez(payload, **arrays)
            atomic_write(self.run.transitions(self.stages[index]), lambda file: file.write(payload.getvalue()))
            return {"episodes": len(data.returns), "intermediate": intermediate, "knocked_out": knocked_out,
                    "target_success_rate": float(data.successes.mean()), "mean_return": float(data.returns.mean())}

        return self._timed(phase, work)

    def transition_data(self, index: int) -> dict:
        path = self.run.transitions(self.stages[index])
        if not path.is_file():
            raise FileNotFoundError(f"{path} does not exist; collect it first (seqdex pipeline, or seqdex "
                                    f"feasibility, which collects it when missing)")
        with np.load(path) as data:
            return {key: data[key] for key in data.files}

    def fit_feasibility(self, index: int, history: int, temporal: bool, path, label: str | None = None,
                        folds: int = 0, **architecture) -> dict:
        """Trains F^{index} on the saved transitions, sets h and writes it to ``path``
        (:func:`~seqdex_drake.chaining.feasibility_fit.fit_and_save`, with this run's F config and h quantile)."""
        config = dataclasses.replace(self.config.feasibility_config(), history=history if temporal else 0,
                                     temporal=temporal, **({"label": label} if label else {}), **architecture)
        return fit_and_save(self.transition_data(index), config, self.config.threshold_quantile, path,
                            self.stages[index - 1], self.stages[index], folds, self.log)

    def transition_bonus(self, phase: str, index: int):
        """The bonus that fine-tunes pi_{index-1} toward states stage ``index`` succeeds from (None: Policy-Seq)."""
        method = self.config.method
        if method == "policy_seq":
            return None
        envs = self.stage_envs()
        source, target = self.stages[index - 1], self.stages[index]
        source_dim = envs[index - 1].observation_space.shape[0]
        if method != "vchain":  # V-Chain's critic needs no data of its own.
            self.collect_transition_data(f"transitions_{phase}", index)

        def work():
            if method == "vchain":
                return {"critic": str(self.run.policy(target))}
            data = self.transition_data(index)
            if method in ("seqdex", "seqdex_no_temporal"):
                return self.fit_feasibility(index, self.config.history, method == "seqdex",
                                            self.run.feasibility(target))
            outcome = {}
            if method == "tstar":
                outcome = fit_tstar(data, source_dim, self.config.seed, self.config.tstar_steps,
                                    self.config.handoff_failures, self.run.tstar(target), self.log, source, target)
            return outcome

        self._timed(phase, work)
        if method in ("seqdex", "seqdex_no_temporal"):
            model = load_feasibility(self.run.feasibility(target)).model
            return model.predict
        if method == "tstar":
            return tstar_bonus(self.run.tstar(target))
        # V-Chain: the next stage's PPO critic on the hand-over observation.
        critic = PPO.resume(self.run.policy(target)).model
        target_dim = envs[index].observation_space.shape[0]
        if target_dim != source_dim:
            raise ValueError(f"V-Chain scores {source}'s terminal observation with {target}'s critic, but they have "
                             f"different layouts ({source_dim} vs {target_dim} dims)")
        critic.eval()

        def value(history):
            with torch.no_grad():
                return float(critic.value(torch.as_tensor(history[-1:], dtype=torch.float32))[0])

        return value

    # -------------------------------------------------------------------------------------------- runs
    def forward(self) -> None:
        """Forward initialization: train each stage in order, stage i+1 from stage i's terminal buffer."""
        stages = self.stages
        for i, task in enumerate(stages):
            buffer = self.run.buffer(stages[i - 1], task) if i > 0 else None
            start = self.initial_checkpoint(i)
            self.train_stage(f"forward_{i}_{task}", i, self.config.stage_steps, start_from=start, buffer_path=buffer,
                             foreign=start is not None)
            if i + 1 < len(stages):
                self.collect_buffer(f"buffer_0_{task}", i)

    def initial_checkpoint(self, index: int):
        """The checkpoint stage ``index``'s forward phase continues (``config.init_checkpoints``), checked against
        the stage: its observation spec and action size must be the stage env's; None if there is none."""
        task = self.stages[index]
        path = self.config.init_checkpoints.get(task)
        if path is None:
            return None
        try:
            state = load_checkpoint(path, map_location="cpu")
        except (CheckpointError, FileNotFoundError) as error:
            raise PipelineError(f"init checkpoint of {task}: {error}") from error
        env = self.stage_envs()[index]
        expected = observation_spec(task, env.observation_space.shape[0]).to_dict()
        if state.get("obs_spec") != expected:
            raise PipelineError(f"init checkpoint {path} records the observation spec {state.get('obs_spec')}, "
                                f"the {task} stage ({self.config.preset} preset) reads {expected}: another task's "
                                f"policy or another preset")
        if state["dims"]["action_dim"] != env.action_space.shape[0]:
            raise PipelineError(f"init checkpoint {path} acts in {state['dims']['action_dim']} dims, the {task} "
                                f"stage in {env.action_space.shape[0]}: another task config")
        return Path(path)

    def backward(self) -> None:
        """Algorithm 1's ``iterations`` passes after the first forward one. Pass m > 1 first runs the forward
        step again: for i = 2..K, rho_i is re-collected from the (fine-tuned) pi_{i-1} and pi_i trains on it for
        ``finetune_steps`` more (stage 1's MDP has not changed, so its forward step is already converged). Every
        pass then fine-tunes backward: for i = K..2 build stage i's bonus and fine-tune pi_{i-1} with
        ``lambda1 R + lambda2 bonus`` (Policy-Seq: no bonus, the same budget)."""
        stages = self.stages
        for phase in (f"forward_{i}_{task}" for i, task in enumerate(stages)):
            if self.run.done(phase) is None:
                raise RuntimeError(f"backward fine-tuning needs the forward phase {phase} of {self.run.root}; run "
                                   f"seqdex pipeline first")
        for m in range(1, self.config.iterations + 1):
            if m > 1:
                self.forward_again(m)
            for i in range(len(stages) - 1, 0, -1):
                bonus = self.transition_bonus(f"bonus_{m}_{stages[i]}", i)
                previous = stages[i - 1]
                buffer = self.run.buffer(stages[i - 2], previous) if i > 1 else None
                self.train_stage(f"finetune_{m}_{previous}", i - 1, self.config.finetune_steps,
                                 start_from=self.run.policy(previous), buffer_path=buffer, bonus=bonus)

    def forward_again(self, m: int) -> None:
        """Pass ``m``'s forward step (m > 1): for i = 2..K, rho_i re-collected from the current pi_{i-1}, then
        pi_i trained on it for ``finetune_steps`` more."""
        stages = self.stages
        for i in range(1, len(stages)):
            self.collect_buffer(f"buffer_{m - 1}_{stages[i - 1]}", i - 1)
            self.train_stage(f"reforward_{m}_{stages[i]}", i, self.config.finetune_steps,
                             start_from=self.run.policy(stages[i]),
                             buffer_path=self.run.buffer(stages[i - 1], stages[i]))

    def adopt_forward(self, other: "Pipeline") -> None:
        """Takes ``other``'s finished forward phase (policies, buffers, records) and, if it has them, its first
        transition rollouts as this run's own: the chained methods share Algorithm 1's forward phase, so a
        comparison may compute it once per seed. Call before :meth:`execute`."""
        for key in ("seed", "stage_steps", "transition_episodes", "episode_length_cap", "hidden_sizes",
                    "num_envs", "backend", "history"):
            if getattr(other.config, key) != getattr(self.config, key):
                raise ValueError(f"cannot share a forward phase across runs that differ in {key}")
        shared = ("forward_", "buffer_0_", "transitions_bonus_1_")  # The first backward pass's data comes from
        for name in ("stages", "buffers", "transitions"):          # the forward policies: the same for all.
            if (other.run.root / name).is_dir():
                shutil.copytree(other.run.root / name, self.run.root / name, dirs_exist_ok=True)
        for phase, outcome in other.run.record["done"].items():
            if phase.startswith(shared):
                self.run.finish(phase, dict(outcome, shared_from=str(other.run.root)))

    def evaluate_chained(self) -> dict:
        envs, policies = self.stage_envs(), self.policies()
        seed = EVAL_SEED + self.config.seed
        results = {"sequential": evaluate_chain(envs, policies, self.config.eval_episodes, seed)}
        if self.config.method in ("seqdex", "seqdex_no_temporal") and self.config.max_switches > 0:
            feasibility = [load_feasibility(self.run.feasibility(task)) for task in self.stages[1:]]
            results["switcher"] = evaluate_chain(envs, policies, self.config.eval_episodes, seed, feasibility,
                                                 self.config.max_switches, max(self.config.history, 1))
        return results

    def execute(self) -> dict:
        """Runs (or resumes) the whole pipeline; writes and returns ``results.json``'s content."""
        start = time.perf_counter()
        if self.config.method in CHAINED_METHODS:
            self.forward()
            self.backward()
            evaluation = self.evaluate_chained()
        else:
            evaluation = run_single_policy(self)
        phases = self.run.record["done"]
        results = {
            "chain": self.chain.name, "stages": self.stages, "method": self.config.method, "seed": self.config.seed,
            "success_rate": evaluation["sequential"]["success_rate"],
            "success_rate_switcher": evaluation.get("switcher", {}).get("success_rate"),
            "evaluation": evaluation, "ppo_steps": sum(p.get("steps", 0) for p in phases.values()),
            "ppo_budget": pipeline_budget(self.config, len(self.stages)),
            "wall_clock_s": sum(p.get("seconds", 0.0) for p in phases.values()),
            "this_invocation_s": time.perf_counter() - start, "phases": phases,
        }
        self.run.write_results(results)
        return results
