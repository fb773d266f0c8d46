"""Demonstration-augmented PPO (DAPG; Rajeswaran et al. 2018): demonstrations, behaviour cloning, the BC term.

A scripted controller (e.g. :class:`~seqdex_drake.tasks.scripted.tool_grasp_script.ScriptedToolGrasp`) is rolled out in
the sub-task's own env; the episodes that the env's success test passes are kept as demonstrations
(:func:`collect_demonstrations`). The actor is warm-started by behaviour cloning on them, with the critic fitted
to their discounted returns (:func:`behaviour_clone`), and PPO then adds ``lambda0 * lambda1^k`` times the
demonstrations' negative log-likelihood to its loss at update ``k`` (:func:`demo_loss`;
``PPOConfig.demo_coef`` / ``demo_decay``).

A demonstration file (``.npz``) records the task, the observation size and the controller's name; loading one for
another task or observation layout is refused with a message naming both.
"""

import dataclasses
import json
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from seqdex_drake.atomic import atomic_write

FORMAT = "seqdex_drake.demonstrations"
VERSION = 1


@dataclasses.dataclass
class Demonstrations:
    """Successful episodes of a controller: the transitions, flattened, with episode boundaries."""

    task: str
    """The sub-task whose env produced them."""
    observations: np.ndarray
    """[N, obs_dim] float32: the observation each action was taken in."""
    actions: np.ndarray
    """[N, action_dim] float32: the controller's actions (in the env's action space, before the env's phases)."""
    rewards: np.ndarray
    """[N] float32: the env's rewards."""
    episode_starts: np.ndarray
    """[E] int64: the index of each episode's first transition (ascending; the last episode ends at N)."""
    source: str = ""
    """The controller that made them."""
    attempts: int = 0
    """Episodes rolled out to get these (successful and not)."""

    def __post_init__(self):
        n = len(self.observations)
        if len(self.actions) != n or len(self.rewards) != n:
            raise ValueError(f"demonstrations: {n} observations, {len(self.actions)} actions and "
                             f"{len(self.rewards)} rewards; they must be as many")

    @property
    def num_episodes(self) -> int:
        return len(self.episode_starts)

    def __len__(self) -> int:
        return len(self.observations)

    def returns(self, gamma: float) -> np.ndarray:
        """[N] discounted return from each transition to its episode's end (a truncation: no bootstrap)."""
        out = np.zeros(len(self), dtype=np.float64)
        ends = list(self.episode_starts[1:]) + [len(self)]
        for start, end in zip(self.episode_starts, ends, strict=True):
            running = 0.0
            for t in range(end - 1, start - 1, -1):
                running = float(self.rewards[t]) + gamma * running
                out[t] = running
        return out.astype(np.float32)

    @classmethod
    def concatenate(cls, parts: list["Demonstrations"]) -> "Demonstrations":
        """One set from several of the same task (e.g. collected in parallel over disjoint seeds)."""
        if not parts or len({part.task for part in parts}) != 1:
            raise ValueError(f"can only concatenate demonstrations of one task, got {[p.task for p in parts]}")
        offsets = np.cumsum([0] + [len(part) for part in parts[:-1]])
        return cls(parts[0].task, np.concatenate([p.observations for p in parts]),
                   np.concatenate([p.actions for p in parts]), np.concatenate([p.rewards for p in parts]),
                   np.concatenate([p.episode_starts + offset for p, offset in zip(parts, offsets, strict=True)]),
                   parts[0].source, sum(p.attempts for p in parts))

    def save(self, path: str | Path) -> Path:
        """Writes the demonstrations atomically as ``.npz`` (with a JSON header)."""
        header = {"format": FORMAT, "version": VERSION, "task": self.task, "source": self.source,
                  "obs_dim": int(self.observations.shape[1]), "attempts": int(self.attempts)}
        arrays = {"header": np.array(json.dumps(header)), "observations": self.observations,
                  "actions": self.actions, "rewards": self.rewards, "episode_starts": self.episode_starts}
        return atomic_write(Path(path), lambda f: np.savez_compressed(f, **arrays))

    @classmethod
    def load(cls, path: str | Path, expected_task: str | None = None,
             expected_obs_dim: int | None = None) -> "Demonstrations":
        """Reads :meth:`save`'s file; ``ValueError`` naming the file if it is not one, or holds another task's
        demonstrations or another observation size."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"demonstration file {path} does not exist; make it with scripts/collect_demos.py")
        try:
            with np.load(path, allow_pickle=False) as data:
                header = json.loads(str(data["header"]))
                arrays = {key: data[key] for key in ("observations", "actions", "rewards", "episode_starts")}
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as error:
            raise ValueError(f"{path} is not a readable demonstration file ({error})") from error
        if header.get("format") != FORMAT:
            raise ValueError(f"{path} is not a demonstration file (format {header.get('format')!r})")
        if expected_task is not None and header["task"] != expected_task:
            raise ValueError(f"{path} holds demonstrations of {header['task']}, not {expected_task}; collect "
                             f"demonstrations of {expected_task}")
        if expected_obs_dim is not None and header["obs_dim"] != expected_obs_dim:
            raise ValueError(f"{path} holds observations of size {header['obs_dim']}, the {header['task']} env "
                             f"gives {expected_obs_dim}: another observation layout; collect them again")
        return cls(header["task"], arrays["observations"].astype(np.float32), arrays["actions"].astype(np.float32),
                   arrays["rewards"].astype(np.float32), arrays["episode_starts"].astype(np.int64),
                   header.get("source", ""), int(header.get("attempts", 0)))


#: ``controller(env, step) -> action``, after ``controller.reset(env)`` (see ``tasks/scripted/tool_grasp_script.py``).
Controller = Callable


def collect_demonstrations(env, controller, task: str, episodes: int, seed: int = 0,
                           max_attempts: int | None = None) -> Demonstrations:
    """Rolls ``controller`` out in ``env`` (seeds ``seed``, ``seed + 1``, ...) until ``episodes`` episodes pass the
    env's success test at their end (or ``max_attempts``, default ``4 * episodes``, are spent); keeps those.

    The controller has ``reset(env)`` and ``action(env, step) -> np.ndarray``. An episode is successful if the
    env reports ``info["success"]`` on its last step (terminated episodes are failures).
    """
    max_attempts = 4 * episodes if max_attempts is None else max_attempts
    observations, actions, rewards, starts = [], [], [], []
    attempts = 0
    while len(starts) < episodes and attempts < max_attempts:
        obs, _ = env.reset(seed=seed + attempts)
        attempts += 1
        controller.reset(env)
        episode_obs, episode_actions, episode_rewards = [], [], []
        for step in range(env.config.episode_length):
            action = np.asarray(controller.action(env, step), dtype=np.float32)
            episode_obs.append(obs)
            episode_actions.append(action)
            obs, reward, terminated, truncated, info = env.step(action)
            episode_rewards.append(reward)
            if terminated or truncated:
                break
        if info.get("success") and not terminated:
            starts.append(sum(len(o) for o in observations))
            observations.append(np.asarray(episode_obs, np.float32))
            actions.append(np.asarray(episode_actions, np.float32))
            rewards.append(np.asarray(episode_rewards, np.float32))
    if not starts:
        raise RuntimeError(f"no successful {task} episode in {attempts} attempts of {type(controller).__name__}")
    return Demonstrations(task, np.concatenate(observations), np.concatenate(actions), np.concatenate(rewards),
                          np.asarray(starts, np.int64), type(controller).__name__, attempts)


def _tensors(demos: Demonstrations, device) -> tuple[torch.Tensor, torch.Tensor]:
    return (torch.as_tensor(demos.observations, device=device), torch.as_tensor(demos.actions, device=device))


def demo_log_likelihood(model, observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """Mean log-likelihood of demonstration ``actions`` under ``model``'s policy (free action dims only)."""
    log_probs, _, _, _ = model.evaluate(observations, actions)
    return log_probs.mean()


def demo_loss(model, demos: Demonstrations, batch_size: int, generator: torch.Generator) -> torch.Tensor:
    """The DAPG term's unweighted loss: the negative log-likelihood of a random demonstration minibatch."""
    index = torch.randint(len(demos), (min(batch_size, len(demos)),), generator=generator)
    observations, actions = _tensors(demos, model.log_std.device)
    return -demo_log_likelihood(model, observations[index], actions[index])


def behaviour_clone(model, demos: Demonstrations, gamma: float, epochs: int = 50, batch_size: int = 256,
                    learning_rate: float = 1e-3, generator: torch.Generator | None = None, std_floor: float = 0.05,
                    input_noise: float = 0.1) -> dict[str, float]:
    """Warm-starts ``model`` on the demonstrations: the observation normalizer absorbs their observations, the
    actor's mean regresses their actions (mean squared error on the free dims; the log-std is left as configured,
    so PPO still explores), and the critic regresses their discounted returns (a warm critic, as DAPG's).

    Two guards against the cloned policy leaving the demonstrations' states and not coming back:

    * ``std_floor``: the normalizer's standard deviation is raised to at least this much per entry. Entries that
      the demonstrations hold constant (a hand joint the controller never moves, hence its previous-action entry)
      would otherwise be scaled by 1e4, so the policy's first small deviation there saturates its input. PPO's
      own observations then dilute the floor away as they are merged in.
    * ``input_noise``: the observations are perturbed by Gaussian noise of this many (floored) standard
      deviations while cloning, so the policy's output varies smoothly around the demonstrated states.

    Returns the final epoch's ``bc/actor_mse`` and ``bc/critic_mse`` (on the perturbed inputs).
    """
    generator = generator if generator is not None else torch.Generator().manual_seed(0)
    device = model.log_std.device
    observations, actions = _tensors(demos, device)
    returns = torch.as_tensor(demos.returns(gamma), device=device)
    model.update_normalizer(observations)
    normalizer = model.obs_normalizer
    with torch.no_grad():
        normalizer.var.clamp_(min=std_floor ** 2)
    noise_std = input_noise * normalizer.var.sqrt().to(observations.dtype)
    free = model.free_actions
    parameters = list(model.actor.parameters()) + list(model.critic.parameters())
    optimizer = torch.optim.Adam(parameters, lr=learning_rate)
    actor_sum = critic_sum = 0.0
    for _ in range(epochs):
        order = torch.randperm(len(demos), generator=generator)
        actor_sum = critic_sum = 0.0
        batches = 0
        for start in range(0, len(demos), batch_size):
            index = order[start:start + batch_size]
            noisy = observations[index] + noise_std * torch.randn(observations[index].shape, generator=generator)
            mean = model.action_mean(noisy)
            actor_loss = ((mean - actions[index]).square() * free).sum(-1).mean()
            critic_loss = (model.value(noisy) - returns[index]).square().mean()
            optimizer.zero_grad()
            (actor_loss + critic_loss).backward()
            optimizer.step()
            actor_sum, critic_sum, batches = actor_sum + actor_loss.item(), critic_sum + critic_loss.item(), batches + 1
        actor_sum, critic_sum = actor_sum / batches, critic_sum / batches
    return {"bc/actor_mse": actor_sum, "bc/critic_mse": critic_sum}
