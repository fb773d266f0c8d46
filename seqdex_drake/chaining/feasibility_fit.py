"""Fitting one transition feasibility function F from a pipeline run's saved transitions and writing it, with its
threshold h, where the switcher and the fine-tuning bonus load it (``feasibility/<task>.pt``)."""

from collections.abc import Callable

import numpy as np

from seqdex_drake.chaining.feasibility import (
    SUCCESS_THRESHOLD,
    FeasibilityConfig,
    cross_validate,
    feasibility_targets,
    feasibility_threshold,
    train_feasibility,
)
from seqdex_drake.chaining.feasibility_io import save_feasibility
from seqdex_drake.tasks.run_config import observation_spec


def fit_and_save(data: dict, config: FeasibilityConfig, threshold_quantile: float, path, source: str, target: str,
                 folds: int = 0, log: Callable[[str], None] = print) -> dict:
    """Trains F for the hand-over ``source`` -> ``target`` on the transitions ``data`` (``histories``, ``returns``,
    ``successes``) with ``config`` (attention over ``config.history`` steps, or the MLP on the last observation;
    ``config.label`` is what F regresses), sets h (the successful returns' ``threshold_quantile``, or
    :data:`~seqdex_drake.chaining.feasibility.SUCCESS_THRESHOLD` for the success label) and writes it to ``path``.
    With ``folds`` >= 2 it also reports the out-of-fold R^2 and AUC of that many stratified folds
    (:func:`~seqdex_drake.chaining.feasibility.cross_validate`; the F written is fitted as without). Returns the
    outcome: h, the label, the validation R^2 and AUC, the folds' figures and the architecture used."""
    targets = feasibility_targets(data["returns"], data["successes"], config.label)
    model, metrics = train_feasibility(data["histories"], targets, config, successes=data["successes"])
    if folds:
        metrics.update(cross_validate(data["histories"], targets, data["successes"], config, folds))
    if config.label == "success":
        threshold = SUCCESS_THRESHOLD
    elif data["successes"].any():
        threshold = feasibility_threshold(data["returns"], data["successes"], threshold_quantile)
    else:  # Without a success h is undefined; the best return seen keeps c > 1 rare. Said loudly.
        threshold = float(max(data["returns"].max(), 1e-6))
        log(f"warning: no successful {target} execution in the transitions; h set to the best return "
            f"{threshold:.3g}, so the switcher will rarely hand over to {target}")
    dim = data["histories"].shape[-1]
    save_feasibility(path, model, config, threshold, observation_spec(source, dim), source_task=source,
                     target_task=target, metrics=metrics)
    return {"threshold": threshold, "label": config.label, "val_r2": float(metrics.get("val_r2", np.nan)),
            "val_auc": float(metrics.get("val_auc", np.nan)), "n_val": int(metrics.get("n_val", 0)),
            **{key: metrics[key] for key in ("cv_auc", "cv_r2", "cv_folds", "cv_n") if key in metrics},
            "history": config.history,
            **{name: getattr(config, name) for name in ("d_model", "heads", "layers", "feedforward")}}
