"""The training loop of :meth:`seqdex_drake.rl.ppo.PPO.train`: collect, update, log, checkpoint, until the step
budget is spent or a stop is requested (its docstring says what it writes and how it stops)."""

import signal
import time
from collections.abc import Sequence
from pathlib import Path

from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from seqdex_drake.rl.checkpoint import capture_rng_state, save_checkpoint
from seqdex_drake.rl.stop_signals import StopSignals


def run_training(ppo, vec_env, run_dir: str | Path, total_steps: int | None = None, callbacks: Sequence = (),
                 progress: bool = True, stop=None) -> dict[str, float]:
    """:meth:`PPO.train <seqdex_drake.rl.ppo.PPO.train>` of ``ppo``; returns the last update's metrics."""
    total_steps = total_steps or ppo.config.total_steps
    if ppo._saved_env_state is not None and vec_env is not ppo._env:
        ppo._restore_env(vec_env, ppo._saved_env_state)
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    own_stop = stop is None
    stop = StopSignals().__enter__() if own_stop else stop
    writer = SummaryWriter(str(run_dir))
    bar = tqdm(total=total_steps, initial=min(ppo.global_step, total_steps), unit="step", disable=not progress,
               dynamic_ncols=True)
    start_time, start_step, metrics = time.perf_counter(), ppo.global_step, ppo.stats.window_metrics()
    saved_at, abandoned = time.monotonic(), False
    try:
        while ppo.global_step < total_steps and stop.received is None:
            step_before = ppo.global_step
            before = {"rng": capture_rng_state({"policy": ppo.generator}), "stats": ppo.stats.state_dict(),
                      "nonfinite_values": ppo.nonfinite_values}  # What collect() changes but the update needs.
            try:
                rollout = ppo.collect(vec_env)
            except Exception:
                if stop.received is None:
                    raise
                ppo._env = None  # The rollout is abandoned: no env state to save; the next collect resets.
                state = {**ppo.state_dict(), **before}
                state["counters"]["num_episodes"] = before["stats"]["num_episodes"]
                save_checkpoint(run_dir / "last.pt", state)
                abandoned = True
                break
            metrics = {**rollout, **ppo.update(), **ppo.stats.window_metrics()}
            metrics["charts/SPS"] = (ppo.global_step - start_step) / max(time.perf_counter() - start_time, 1e-9)
            for key, value in metrics.items():
                writer.add_scalar(key, value, ppo.global_step)
            bar.update(min(ppo.global_step, total_steps) - min(step_before, total_steps))
            bar.set_postfix({"SPS": f"{metrics['charts/SPS']:.0f}", **{
                name: f"{metrics[key]:.2f}" for name, key in (("success", "charts/success_rate"),
                                                             ("ret", "charts/episode_return")) if key in metrics}})
            selection = ppo.stats.selection_metric()
            if selection is not None and selection[1] > ppo.best["value"]:
                ppo.best = {"metric": selection[0], "value": selection[1]}
                ppo.save(run_dir / "best.pt")
            if (ppo.num_updates % ppo.config.checkpoint_every == 0
                    or time.monotonic() - saved_at >= ppo.config.checkpoint_seconds):
                ppo.save(run_dir / "last.pt")
                saved_at = time.monotonic()
            if any(callback(ppo, metrics) is False for callback in callbacks):
                break
        if not abandoned:
            ppo.save(run_dir / "last.pt")
    finally:
        writer.close()
        bar.close()
        if own_stop:
            stop.__exit__(None, None, None)
    if own_stop and stop.signum is not None:  # last.pt is saved: now the previous handler's turn.
        signal.raise_signal(stop.signum)
    return metrics
