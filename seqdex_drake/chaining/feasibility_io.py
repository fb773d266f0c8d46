"""The feasibility function's file: one ``torch.save`` dict of tensors and plain data (loads with
``weights_only=True``, so loading never runs pickled code), written atomically.

It records the format tag and version, the source and target task names (F^i scores pi^{i-1}'s transition
histories for pi^i), the observation spec, H, the model kind, the config, the threshold h, optional training
metrics and the weights (observation normalizer and return scale included). Use through
:func:`seqdex_drake.chaining.feasibility.save_feasibility` / ``load_feasibility``.
"""

import dataclasses
import io
import os
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from seqdex_drake.atomic import atomic_write
from seqdex_drake.chaining.feasibility import FeasibilityConfig, build_feasibility_model
from seqdex_drake.observation_spec import ObservationSpec

if TYPE_CHECKING:
    from seqdex_drake.chaining.feasibility import FeasibilityConfig

FORMAT = "seqdex_drake.chaining.feasibility"
VERSION = 1


@dataclasses.dataclass
class FeasibilityFile:
    """What :func:`load_feasibility` returns."""

    model: torch.nn.Module
    """The feasibility model (eval mode, CPU unless ``map_location`` says otherwise)."""
    config: "FeasibilityConfig"
    """The config it was built and trained with."""
    threshold: float
    """h: switch to ``target_task`` when F / h > 1."""
    obs_spec: ObservationSpec
    """The observations it reads."""
    source_task: str
    """The sub-task whose terminal histories it scores (pi^{i-1})."""
    target_task: str
    """The sub-task whose return it predicts (pi^i)."""
    metrics: dict
    """Training metrics stored with it (may be empty)."""


def save_feasibility(path: str | os.PathLike, model, config: "FeasibilityConfig", threshold: float,
                     obs_spec: ObservationSpec, *, source_task: str, target_task: str,
                     metrics: dict | None = None) -> Path:
    """Atomically writes the model and everything needed to use it; returns the path."""
    if model.obs_dim != obs_spec.dim:
        raise ValueError(f"the model reads {model.obs_dim}-dim observations but the spec says {obs_spec}")
    if not threshold > 0:
        raise ValueError(f"the threshold h must be positive, got {threshold}")
    payload = {
        "format": FORMAT, "version": VERSION, "source_task": str(source_task), "target_task": str(target_task),
        "obs_spec": obs_spec.to_dict(), "history": int(config.history),
        "kind": "temporal" if config.uses_attention else "mlp", "config": dataclasses.asdict(config),
        "threshold": float(threshold), "metrics": {k: float(v) for k, v in (metrics or {}).items()},
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }
    buffer = io.BytesIO()
    torch.save(payload, buffer)  # Serialize fully before touching the destination.
    return atomic_write(path, lambda file: file.write(buffer.getvalue()))


def load_feasibility(path: str | os.PathLike, expected_obs_spec: ObservationSpec | None = None, *,
                     expected_target_task: str | None = None, map_location="cpu") -> FeasibilityFile:
    """Reads a file written by :func:`save_feasibility`.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a feasibility file, another format version, or a different observation spec or target
            task than expected (the message names both).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"feasibility model {path} does not exist; train the feasibility function first")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as error:  # noqa: BLE001 - torch raises many types for damaged files.
        raise ValueError(f"{path} is not a readable feasibility file ({type(error).__name__}: {error})") from error
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path} is not a feasibility file (no '{FORMAT}' format tag)")
    if payload.get("version") != VERSION:
        raise ValueError(f"{path} has feasibility format version {payload.get('version')}, this code reads "
                         f"version {VERSION}; retrain it")
    obs_spec = ObservationSpec.from_dict(payload["obs_spec"])
    obs_spec.check(expected_obs_spec, f"feasibility model {path}")
    if expected_target_task is not None and payload["target_task"] != expected_target_task:
        raise ValueError(f"feasibility model {path} predicts the return of task {payload['target_task']!r}, but "
                         f"{expected_target_task!r} was expected")
    config = FeasibilityConfig(**payload["config"])
    model = build_feasibility_model(obs_spec.dim, config)
    model.load_state_dict(payload["state_dict"])
    model.to(map_location).eval()
    return FeasibilityFile(model=model, config=config, threshold=float(payload["threshold"]), obs_spec=obs_spec,
                           source_task=payload["source_task"], target_task=payload["target_task"],
                           metrics=dict(payload["metrics"]))
