"""The baselines that train one policy over the whole chain: RL-scratch and Curriculum RL.

Both run PPO on :class:`~seqdex_drake.envs.chain_env.ChainEnv` (the stages back to back in one episode, the
stage as a one-hot in the observation) with the same total budget as the chained methods
(:func:`~seqdex_drake.chaining.pipeline.pipeline_budget`). RL-scratch always starts at the first stage;
Curriculum RL splits the budget into K phases whose episodes start at stage K-1, K-2, ..., 0 (from that stage's
own reset distribution), moving the start progressively earlier along the chain.
"""

import numpy as np

from seqdex_drake.chaining.pipeline import EVAL_SEED, pipeline_budget
from seqdex_drake.chaining.rollouts import deterministic_policy
from seqdex_drake.chaining.stage_envs import pooled_env
from seqdex_drake.rl.ppo import PPO


def _chain_env(pipeline, slot: int, start_stage: int = 0):
    """A ChainEnv (the pipeline's ``env_kit.chain_env``) over the process's pooled stage envs number ``slot``."""
    envs = [pooled_env(task, config, slot) for task, config in zip(pipeline.stages, pipeline.task_configs,
                                                                   strict=True)]
    return pipeline.require_env_kit().chain_env(pipeline.stages, start_stage=start_stage, envs=envs)


def _chain_vector_env(pipeline, start_stage: int, seed: int):
    return pipeline.require_env_kit().serial_vector_env(
        [lambda slot=slot: _chain_env(pipeline, 1 + slot, start_stage) for slot in range(pipeline.config.num_envs)],
        seed=seed)


def _train_phase(pipeline, phase: str, start_stage: int, steps: int, start_from=None) -> dict:
    def work():
        directory = pipeline.run.phase_dir(phase)
        ppo, target = pipeline.phase_learner(phase, steps, start_from)
        env = _chain_vector_env(pipeline, start_stage, pipeline.config.seed + 17 * start_stage)
        try:
            if ppo is None:
                ppo = PPO.for_env(pipeline._ppo_config(pipeline.stages[0]), env)
            metrics = ppo.train(env, directory, total_steps=target, progress=pipeline.progress)
        finally:
            env.close()
        return {"steps": steps, "start_stage": start_stage,
                "success_rate": float(metrics.get("charts/success_rate", np.nan))}

    return pipeline._timed(phase, work)


def evaluate_single_policy(pipeline, checkpoint) -> dict:
    """Chain success of one policy over ``eval_episodes`` ChainEnv episodes from the first stage."""
    policy = deterministic_policy(PPO.resume(checkpoint))
    env = _chain_env(pipeline, 0)
    successes, steps = [], []
    for episode in range(pipeline.config.eval_episodes):
        observation, info = env.reset(seed=EVAL_SEED + pipeline.config.seed + episode)
        count = 0
        while True:
            observation, _, terminated, truncated, info = env.step(policy(observation))
            count += 1
            if terminated or truncated:
                break
        successes.append(bool(info["success"]))
        steps.append(count)
    return {"success_rate": float(np.mean(successes)), "mean_switches": 0.0, "mean_steps": float(np.mean(steps)),
            "episodes": pipeline.config.eval_episodes}


def run_single_policy(pipeline) -> dict:
    """Trains the RL-scratch or Curriculum RL policy in ``pipeline``'s run directory and evaluates it."""
    budget = pipeline_budget(pipeline.config, len(pipeline.stages))
    if pipeline.config.method == "scratch":
        phases = [("scratch", 0, budget)]
    else:
        count = len(pipeline.stages)
        shares = [budget // count + (1 if k < budget % count else 0) for k in range(count)]
        phases = [(f"curriculum_{k}_start_{s}", s, shares[k]) for k, s in enumerate(range(count - 1, -1, -1))]
    previous = None
    for phase, start_stage, steps in phases:
        _train_phase(pipeline, phase, start_stage, steps, start_from=previous)
        previous = pipeline.run.phase_dir(phase) / "last.pt"
    return {"sequential": evaluate_single_policy(pipeline, previous)}
