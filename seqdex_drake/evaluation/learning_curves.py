"""Learning curves of training runs: success rate and return against env steps and wall-clock, as CSV and PNG.

The source is the TensorBoard event files that :meth:`~seqdex_drake.rl.ppo.PPO.train` writes into a run directory
(``charts/success_rate``, ``charts/episode_return``, ``charts/SPS``; one point per PPO update). A run resumed
over several sessions has several event files; their points are merged by env step (the later file wins where a
resumed run repeats steps), and wall-clock is the sum of the time between consecutive updates within each file,
so that the pauses between sessions do not count.
"""

import csv
import math
from pathlib import Path

import numpy as np

#: TensorBoard scalar -> CSV column.
COLUMNS = {"charts/success_rate": "success_rate", "charts/episode_return": "episode_return",
           "charts/episode_length": "episode_length", "losses/demo_weight": "demo_weight"}


def read_curve(run_dir: str | Path) -> dict[str, np.ndarray]:
    """The run's curve: ``env_steps``, ``wall_clock_s`` and the :data:`COLUMNS` (NaN where not logged), sorted
    by env step. Raises ValueError if ``run_dir`` holds no event file with any of them."""
    # Start-up time: tensorboard loads slowly, and only this reader needs it.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run_dir = Path(run_dir)
    files = sorted(run_dir.glob("events.out.tfevents.*"), key=lambda path: path.stat().st_mtime)
    points: dict[int, dict[str, float]] = {}
    elapsed_before = 0.0
    for path in files:
        events = EventAccumulator(str(path), size_guidance={"scalars": 0})
        events.Reload()
        tags = set(events.Tags()["scalars"])
        if "charts/SPS" not in tags:
            continue
        times = {event.step: event.wall_time for event in events.Scalars("charts/SPS")}
        steps = sorted(times)
        # The first update's own duration is not in the file: estimated from the rate it logged, over one batch
        # (the step gap to the next update) when the file continues a run whose earlier updates are elsewhere.
        first_sps = next(event.value for event in events.Scalars("charts/SPS") if event.step == steps[0])
        batch = steps[1] - steps[0] if len(steps) > 1 else steps[0]
        previous = max((step for step in points if step < steps[0]), default=max(steps[0] - batch, 0))
        start = times[steps[0]] - (steps[0] - previous) / max(first_sps, 1e-9)
        for step in steps:
            points.setdefault(step, {})["wall_clock_s"] = elapsed_before + (times[step] - start)
        for tag, column in COLUMNS.items():
            if tag in tags:
                for event in events.Scalars(tag):
                    points.setdefault(event.step, {})[column] = event.value
        elapsed_before = points[steps[-1]]["wall_clock_s"]
    if not points:
        raise ValueError(f"{run_dir} holds no training events (charts/SPS); is it a seqdex train run directory?")
    steps = sorted(points)
    curve = {"env_steps": np.array(steps, dtype=np.int64)}
    for column in ["wall_clock_s", *COLUMNS.values()]:
        curve[column] = np.array([points[step].get(column, math.nan) for step in steps], dtype=float)
    return curve


def write_curve(run_dir: str | Path, out: str | Path, title: str = "") -> tuple[Path, Path]:
    """Writes ``out.csv`` and ``out.png`` (success rate and return against env steps and wall-clock hours)."""
    import matplotlib  # Start-up time: matplotlib only for the figures, off-screen (Agg).

    matplotlib.use("Agg")
    from matplotlib import pyplot  # After use("Agg"), so no display is needed.

    curve = read_curve(run_dir)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    csv_path, png_path = out.with_suffix(".csv"), out.with_suffix(".png")
    with csv_path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(list(curve))
        for row in zip(*curve.values(), strict=True):
            writer.writerow([f"{value:.6g}" if isinstance(value, float) else int(value) for value in row])
    figure, axes = pyplot.subplots(2, 2, figsize=(10, 6), sharey="row")
    hours = curve["wall_clock_s"] / 3600.0
    for column, (key, label) in enumerate((("env_steps", "env steps"), ("hours", "wall-clock (h)"))):
        x = curve["env_steps"] if key == "env_steps" else hours
        axes[0, column].plot(x, curve["success_rate"], color="tab:green")
        axes[0, column].set_ylabel("success rate (last 100 episodes)")
        axes[1, column].plot(x, curve["episode_return"], color="tab:blue")
        axes[1, column].set_ylabel("episode return (last 100)")
        axes[1, column].set_xlabel(label)
        for row in range(2):
            axes[row, column].grid(alpha=0.3)
    figure.suptitle(title or Path(run_dir).name)
    figure.tight_layout()
    figure.savefig(png_path, dpi=100)
    pyplot.close(figure)
    return csv_path, png_path
