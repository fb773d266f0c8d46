"""The feasibility pose scatter (paper Fig. 6 style): the target object's roll, pitch and yaw at the control
ticks where a feasibility function scored the transition feasible (c > 1), over the ticks where it did not.

Written with matplotlib's Agg backend (matplotlib comes with drake); the points also go to a CSV.
"""

import csv
from pathlib import Path

import numpy as np

PAIRS = ((0, 2, "roll", "yaw"), (0, 1, "roll", "pitch"), (2, 1, "yaw", "pitch"))


def write_pose_scatter(path: Path, rpy: np.ndarray, scores: np.ndarray, title: str, note: str = "") -> Path:
    """Writes the scatter PNG at ``path`` and the points to ``path.with_suffix('.csv')``.

    Args:
        rpy: (n, 3) roll, pitch, yaw (rad) of the object at the scored ticks.
        scores: (n,) the feasibility score c at those ticks.
        title: the figure title (e.g. which transition).
        note: shown under the title when there is nothing to plot (why).
    """
    import matplotlib  # Start-up time: matplotlib only for the figures, off-screen (Agg).

    matplotlib.use("Agg")
    from matplotlib import pyplot  # After use("Agg"), so no display is needed.

    path.parent.mkdir(parents=True, exist_ok=True)
    rpy = np.degrees(np.asarray(rpy, dtype=float).reshape(-1, 3))
    scores = np.asarray(scores, dtype=float).reshape(-1)
    feasible = scores > 1.0
    with path.with_suffix(".csv").open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["roll_deg", "pitch_deg", "yaw_deg", "c", "feasible"])
        for row, c, ok in zip(rpy, scores, feasible, strict=True):
            writer.writerow([f"{row[0]:.3f}", f"{row[1]:.3f}", f"{row[2]:.3f}", f"{c:.4f}", int(ok)])
    figure, axes = pyplot.subplots(1, 3, figsize=(12, 4), dpi=100)
    for axis, (i, j, x_name, y_name) in zip(axes, PAIRS, strict=True):
        axis.scatter(rpy[~feasible, i], rpy[~feasible, j], s=6, c="#bbbbbb", label="c <= 1")
        axis.scatter(rpy[feasible, i], rpy[feasible, j], s=10, c="#1f9e3a", label="c > 1")
        axis.set_xlim(-180, 180)
        axis.set_ylim(-180 if y_name != "pitch" else -90, 180 if y_name != "pitch" else 90)
        axis.set_xlabel(f"{x_name} (deg)")
        axis.set_ylabel(f"{y_name} (deg)")
        axis.grid(True, alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    subtitle = f"{int(feasible.sum())} of {scores.size} scored ticks with c > 1" if scores.size else note
    figure.suptitle(f"{title}\n{subtitle}", fontsize=10)
    figure.tight_layout()
    figure.savefig(path)
    pyplot.close(figure)
    return path
