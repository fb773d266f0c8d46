"""Rolling chains out in-process: one stage, the transitions that train F, and whole-chain evaluation.

Stage envs are :class:`~seqdex_drake.envs.subtask_env.SubtaskEnv`-like (``reset(seed, options)``, ``step``,
``get_state``, ``config.episode_length``) and share one scene, so a state moves between them with
``reset(options={"initial_state": state})``. A policy is any callable from an observation to an action (see
:func:`deterministic_policy`). Each stage runs for its own ``episode_length`` steps (its time budget) unless it
fails first; the switcher (:func:`evaluate_chain` with feasibility functions) may hand over earlier.

Every reset is seeded, hand-overs included (:func:`handover_seed`): a stage that draws on a hand-over (Insert
draws its plate and goal) draws the same for the same episode seed, whatever its env did before.
"""

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np
import torch

from seqdex_drake.chaining.feasibility import pad_history, walk_back
from seqdex_drake.env_state import SceneHandoffError

Policy = Callable[[np.ndarray], np.ndarray]


def handover_seed(seed: int, run: int) -> int:
    """The reset seed of the ``run``-th stage run (``run`` >= 1; run 0 uses ``seed`` itself) of the episode seeded
    ``seed``: derived from both, so that hand-overs draw the same for the same episode and differ across runs and
    episodes (an unseeded reset would draw from whatever the env's generator holds, a fresh env's from the OS)."""
    return int(np.random.SeedSequence([int(seed), int(run)]).generate_state(1)[0])


def deterministic_policy(ppo) -> Policy:
    """The mean action of a :class:`~seqdex_drake.rl.ppo.PPO` learner, clipped to [-1, 1], as a callable."""
    ppo.model.eval()

    def act(observation: np.ndarray) -> np.ndarray:
        obs = torch.as_tensor(np.asarray(observation, dtype=np.float32)[None], device=ppo.device)
        with torch.no_grad():
            return np.clip(ppo.model.action_mean(obs)[0].cpu().numpy(), -1.0, 1.0)

    return act


@dataclasses.dataclass
class StageResult:
    """One stage's run."""

    observations: np.ndarray
    """(T + 1, obs_dim): the first observation and every step's."""
    episode_return: float
    success: bool
    """The stage's success test at its last step."""
    failed: bool
    """The stage ended in task failure (terminated) or a simulator error."""
    state: object
    """The env's state at the end (hand it to the next stage)."""


def run_stage(env, policy: Policy, *, seed: int | None = None, initial_state=None,
              stop: Callable[[np.ndarray], bool] | None = None,
              before_step: Callable[[object, int], None] | None = None) -> StageResult:
    """Runs ``policy`` in ``env`` from a reset seeded ``seed`` (from ``initial_state`` if given; seed it too, see
    :func:`handover_seed`) until its time budget, a failure, or ``stop(observations so far)`` is true (the
    switcher's early hand-over). ``before_step(env, step)``, if given, may change the scene before each step
    (e.g. knock the object out of the hand); the policy then acts on the observation taken before it."""
    options = None if initial_state is None else {"initial_state": initial_state}
    observation, info = env.reset(seed=seed, options=options)
    observations, total, failed = [observation], 0.0, False
    while True:
        if before_step is not None:
            before_step(env, len(observations) - 1)
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        observations.append(observation)
        total += reward
        failed = bool(terminated or info.get("simulator_error") or info.get("nan_action"))
        if terminated or truncated or (stop is not None and stop(np.stack(observations))):
            break
    return StageResult(np.stack(observations), total, bool(info.get("success", False)) and not failed, failed,
                       env.get_state())


def run_prefix(envs: Sequence, policies: Sequence[Policy], upto: int, seed: int) -> StageResult:
    """Runs stages ``0 .. upto`` in order from stage 0's reset (``seed``), each from the previous one's final
    state; returns stage ``upto``'s result (its final state is the hand-over to stage ``upto + 1``)."""
    state, result = None, None
    for stage in range(upto + 1):
        result = run_stage(envs[stage], policies[stage], seed=seed if stage == 0 else handover_seed(seed, stage),
                           initial_state=state)
        state = result.state
    return result


@dataclasses.dataclass
class Transitions:
    """What F^i learns from: pi^{i-1}'s terminal histories and pi^i's returns from those states."""

    histories: np.ndarray
    """(N, H, obs_dim of stage i-1)."""
    returns: np.ndarray
    """(N,) pi^i's returns."""
    successes: np.ndarray
    """(N,) pi^i's success."""
    source_successes: np.ndarray
    """(N,) pi^{i-1}'s success at the hand-over."""
    states: list
    """The hand-over states (pi^i's initial states), for T-STAR's discriminator."""
    target_observations: np.ndarray
    """(N, obs_dim of stage i): pi^i's first observation from each hand-over state (V-Chain's critic input)."""


def collect_transitions(envs: Sequence, policies: Sequence[Policy], target: int, episodes: int, seed: int,
                        history: int = 10, intermediate: int = 0, knocked_out: int = 0,
                        knock_out: Callable[[object, np.random.Generator], None] | None = None) -> Transitions:
    """Runs the chain prefix ``0 .. target`` ``episodes`` times (episode ``e`` seeded ``seed + e``), handing each
    stage's final state to the next, and records pi^{target-1}'s last ``history`` observations with
    pi^{target}'s return and success (successes and failures alike: F must learn both).

    ``intermediate`` more episodes (seeded ``seed + episodes + e``) hand over early, after a uniformly drawn
    number of pi^{target-1}'s steps (1 .. its budget - 1): the switcher scores F on every tick of stage
    ``target - 1``, so an F meant for switching must also have seen the states before that stage's end (from which
    pi^{target} mostly fails) rather than extrapolate to them from terminal states alone.

    ``knocked_out`` more episodes (seeded ``seed + episodes + intermediate + e``) run pi^{target-1} to its end with
    ``knock_out(env, rng)`` applied after a uniformly drawn number of its steps (its second half): the object
    knocked out of the hand, so F also knows a dropped object, from which the switcher should go back rather
    than on (the paper's recovery)."""
    if knocked_out and knock_out is None:
        raise ValueError("knocked_out episodes need a knock_out function (e.g. tasks.tools_common.knock_out_tool)")
    if not 1 <= target < len(envs):
        raise ValueError(f"target must be in [1, {len(envs) - 1}] (F^1 does not exist), got {target}")
    rows = {key: [] for key in ("histories", "returns", "successes", "source_successes", "states", "first")}
    length = envs[target - 1].config.episode_length
    cuts = np.random.default_rng([seed, target]).integers(1, length, size=intermediate)
    knocks = np.random.default_rng([seed, target, 1]).integers(length // 2, length, size=knocked_out)
    for episode in range(episodes + intermediate + knocked_out):
        if episode < episodes:
            result = run_prefix(envs, policies, target - 1, seed + episode)
        elif episode < episodes + intermediate:
            cut = int(cuts[episode - episodes])
            result = _source_run(envs, policies, target, seed + episode,
                                 stop=lambda observations, cut=cut: len(observations) > cut)
        else:
            at, rng = int(knocks[episode - episodes - intermediate]), np.random.default_rng([seed, episode])

            def knock(env, step, at=at, rng=rng):
                if step == at:
                    knock_out(env, rng)

            result = _source_run(envs, policies, target, seed + episode, before_step=knock)
        state = result.state
        nxt = run_stage(envs[target], policies[target], initial_state=state, seed=handover_seed(seed + episode, target))
        rows["histories"].append(pad_history(result.observations, history))
        rows["returns"].append(nxt.episode_return)
        rows["successes"].append(nxt.success)
        rows["source_successes"].append(result.success)
        rows["states"].append(state)
        rows["first"].append(nxt.observations[0])
    return Transitions(np.stack(rows["histories"]), np.array(rows["returns"]), np.array(rows["successes"]),
                       np.array(rows["source_successes"]), rows["states"], np.stack(rows["first"]))


def _source_run(envs: Sequence, policies: Sequence[Policy], target: int, seed: int, **run) -> StageResult:
    """Stage ``target - 1``'s run of the episode seeded ``seed`` (from the chain prefix before it), with
    :func:`run_stage`'s ``stop`` / ``before_step`` in ``run``."""
    before = None if target == 1 else run_prefix(envs, policies, target - 2, seed).state
    return run_stage(envs[target - 1], policies[target - 1], initial_state=before,
                     seed=seed if target == 1 else handover_seed(seed, target - 1), **run)


@dataclasses.dataclass
class ChainOutcome:
    success: bool
    """The last stage's success test at the end of its budget."""
    stages_run: list[int]
    """Stage indices in the order they ran (switches show as repeats or jumps)."""
    switches: int
    """Stage selections that were not the plain sequential successor (bypass, recovery, restart)."""
    steps: int


def _scores(feasibility: Sequence, history: np.ndarray) -> np.ndarray:
    """c^j = F^j / h^j for j = 1..K-1 (index j scores the hand-over to stage j); NaN where F^j reads another
    observation layout than the active stage's (it cannot be evaluated on this history)."""
    scores = np.full(len(feasibility) + 1, np.nan)
    for j, entry in enumerate(feasibility, start=1):
        if entry is not None and entry.model.obs_dim == history.shape[-1]:
            scores[j] = entry.model.predict(history) / entry.threshold
    return scores


def run_chain(envs: Sequence, policies: Sequence[Policy], seed: int, feasibility: Sequence | None = None,
              max_switches: int = 0, history: int = 10) -> ChainOutcome:
    """One chain episode from stage 0's reset distribution.

    With ``max_switches = 0`` (or no feasibility functions) the stages run in order, each for its time budget
    (plain sequential execution). Otherwise the paper's switcher runs: in stage i, once the next stage's score
    c^{i+1} = F^{i+1}/h^{i+1} exceeds 1 (or stage i's budget runs out), the stages are visited from the last
    back to the second and the first with c > 1 runs next (a bypass if it is beyond i+1); if none qualifies the
    chain restarts with stage 0 from the current state (:func:`~seqdex_drake.chaining.feasibility.walk_back`, the
    rule the chain controller's switcher uses). Each selection other than i+1 uses up one switch; with none
    left the order is sequential. The last stage's budget (or a failure) ends the episode. A switch back to a stage
    whose scene cannot take the state (Building Blocks: Search's pile from a single-block scene; the whole-chain
    scene keeps every block, the envs do not) ends it as a failure.
    ``feasibility[j-1]`` is F^j (objects with ``.model`` and ``.threshold``, e.g. a
    :class:`~seqdex_drake.chaining.feasibility_io.FeasibilityFile`; None for a missing one).
    """
    switching = max_switches > 0 and feasibility is not None
    last = len(envs) - 1
    stage, state, switches, steps, stages_run = 0, None, 0, 0, []
    budget = sum(env.config.episode_length for env in envs) * (1 + max_switches)
    while True:
        stages_run.append(stage)

        def early(observations, stage=stage):
            if not switching or stage == last:
                return False
            return bool(_scores(feasibility, pad_history(observations, history))[stage + 1] > 1.0)

        try:
            result = run_stage(envs[stage], policies[stage], initial_state=state, stop=early,
                               seed=seed if state is None else handover_seed(seed, len(stages_run) - 1))
        except SceneHandoffError:  # A switch back to a scene that cannot hold this state (a single block handed
            return ChainOutcome(False, stages_run, switches, steps)  # back to the pile): the episode fails.
        steps += len(result.observations) - 1
        state = result.state
        if stage == last:  # The last stage's budget (or a failure) ends the chain episode.
            return ChainOutcome(result.success, stages_run, switches, steps)
        if result.failed or steps >= budget:
            return ChainOutcome(False, stages_run, switches, steps)
        following = stage + 1
        if switching and switches < max_switches:
            scores = _scores(feasibility, pad_history(result.observations, history))
            chosen = walk_back(scores)
            if chosen != following:
                switches += 1
            following = chosen
        stage = following


def evaluate_chain(envs: Sequence, policies: Sequence[Policy], episodes: int, seed: int,
                   feasibility: Sequence | None = None, max_switches: int = 0, history: int = 10) -> dict:
    """Success rate of ``episodes`` chain episodes (episode ``e`` seeded ``seed + e``), see :func:`run_chain`."""
    outcomes = [run_chain(envs, policies, seed + e, feasibility, max_switches, history) for e in range(episodes)]
    return {"success_rate": float(np.mean([o.success for o in outcomes])),
            "mean_switches": float(np.mean([o.switches for o in outcomes])),
            "mean_steps": float(np.mean([o.steps for o in outcomes])), "episodes": episodes}
