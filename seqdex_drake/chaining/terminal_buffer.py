"""Forward initialization's hand-off file (Algorithm 1's terminal-state buffer B^i).

Rolling out pi^{i-1} (the *source* task) records, per episode, the environment state at its end, the last H
observations ending there (the feasibility function's input) and the episode's return and success; the *target*
task pi^i then starts episodes from states sampled out of the buffer.

File: one ``.npz`` (read with ``allow_pickle=False``: loading never runs pickled code), written atomically. It
holds a JSON ``meta`` record (format tag, version, source and target task, scenario, observation spec, H, and
the state schema), ``histories`` (N, H, obs_dim) float32, ``returns`` (N,) float64, ``successes`` (N,) bool, and
one stacked array per state field, ``state__<path>``, (N, ...).

States are stored generically, field by field, so this module needs no Drake: a state is a dataclass (the env's
``EnvState``) or a mapping whose values are numpy arrays, numbers, strings or nested mappings of those; nested
keys are joined with ".". Every entry of one buffer must share the first entry's fields, shapes and dtypes
(one scenario gives one layout). Sampled states come back as nested dicts of numpy arrays (strings and python
numbers restored as such), or as ``state_type(**fields)`` when a type is given (e.g. ``EnvState``).
"""

import dataclasses
import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from seqdex_drake.atomic import atomic_write
from seqdex_drake.observation_spec import ObservationSpec

#: H of the buffers ``seqdex collect`` writes: the observations stored per entry (the feasibility function's input
#: length, the paper's 10).
HISTORY = 10
FORMAT = "seqdex_drake.chaining.terminal_buffer"
VERSION = 1
_STATE_PREFIX = "state__"


@dataclasses.dataclass
class TerminalEntry:
    """One recorded transition state."""

    state: object
    """The environment state (nested dict of arrays, or ``state_type`` instance)."""
    history: np.ndarray
    """(H, obs_dim) observations ending at the state, oldest first."""
    episode_return: float
    """Return of the source episode that ended here."""
    success: bool
    """Whether that episode succeeded at the source task."""


def _flatten(state, prefix: str = "") -> dict[str, tuple[str, np.ndarray]]:
    """{dotted path: (kind, array)} with kind "array", "str", "int", "float" or "bool"."""
    if dataclasses.is_dataclass(state) and not isinstance(state, type):
        state = {field.name: getattr(state, field.name) for field in dataclasses.fields(state)}
    if not isinstance(state, Mapping):
        raise TypeError(f"a state must be a dataclass or a mapping, got {type(state).__name__}")
    flat = {}
    for key, value in state.items():
        if not isinstance(key, str) or not key or "." in key:
            raise ValueError(f"state keys must be non-empty strings without '.', got {key!r}")
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, path + "."))
        elif isinstance(value, str):
            flat[path] = ("str", np.asarray(value))
        elif isinstance(value, bool | int | float):
            flat[path] = (type(value).__name__, np.asarray(value))
        else:
            array = np.asarray(value)
            if array.dtype == object:
                raise TypeError(f"state field {path!r} is not a numeric/bool/str array ({type(value).__name__})")
            flat[path] = ("array", array)
    return flat


def _unflatten(flat: dict[str, object]) -> dict:
    nested: dict = {}
    for path, value in flat.items():
        node = nested
        *parents, leaf = path.split(".")
        for parent in parents:
            node = node.setdefault(parent, {})
        node[leaf] = value
    return nested


class TerminalBuffer:
    """Terminal states of ``source_task`` episodes, to start ``target_task`` episodes from.

    Args:
        source_task: the task whose policy produced the states (pi^{i-1}).
        target_task: the task that starts from them (pi^i).
        scenario: the scenario (file or name) the states belong to.
        obs_spec: the observations in ``histories``.
        history: H, the observations stored per entry.
    """

    def __init__(self, source_task: str, target_task: str, scenario: str, obs_spec: ObservationSpec,
                 history: int):
        if history < 1:
            raise ValueError(f"history must be >= 1, got {history}")
        self.source_task, self.target_task, self.scenario = str(source_task), str(target_task), str(scenario)
        self.obs_spec, self.history = obs_spec, int(history)
        self._schema: dict[str, dict] | None = None  # path -> {"kind", "dtype", "shape"}
        self._states: dict[str, list[np.ndarray]] = {}
        self._histories: list[np.ndarray] = []
        self._returns: list[float] = []
        self._successes: list[bool] = []

    def __len__(self) -> int:
        return len(self._returns)

    def append(self, state, history, episode_return: float, success: bool = True) -> None:
        """Adds one entry; ``history`` is (T, obs_dim) with T >= H (the last H rows are kept)."""
        history = np.asarray(history, dtype=np.float32)
        if history.ndim != 2 or history.shape[1] != self.obs_spec.dim or history.shape[0] < self.history:
            raise ValueError(f"history must be (>= {self.history}, {self.obs_spec.dim}), got {history.shape}; pad "
                             f"short episodes with feasibility.pad_history")
        flat = _flatten(state)
        schema = {path: {"kind": kind, "dtype": array.dtype.str, "shape": list(array.shape)}
                  for path, (kind, array) in flat.items()}
        if self._schema is None:
            self._schema = schema
            self._states = {path: [] for path in schema}
        else:
            self._check_schema(schema)
        for path, (_, array) in flat.items():
            self._states[path].append(array)
        self._histories.append(history[-self.history:])
        self._returns.append(float(episode_return))
        self._successes.append(bool(success))

    def _check_schema(self, schema: dict) -> None:
        if set(schema) != set(self._schema):
            raise ValueError(f"state fields {sorted(schema)} differ from the buffer's {sorted(self._schema)}")
        for path, entry in schema.items():
            known = self._schema[path]
            same_dtype = entry["dtype"] == known["dtype"] or (entry["kind"] == known["kind"] == "str")
            if entry["kind"] != known["kind"] or entry["shape"] != known["shape"] or not same_dtype:
                raise ValueError(f"state field {path!r} is {entry}, but the buffer holds {known}")

    @property
    def histories(self) -> np.ndarray:
        """(N, H, obs_dim) float32."""
        return np.stack(self._histories) if self._histories else np.zeros((0, self.history, self.obs_spec.dim),
                                                                         np.float32)

    @property
    def returns(self) -> np.ndarray:
        """(N,) float64 source-episode returns."""
        return np.asarray(self._returns, dtype=np.float64)

    @property
    def successes(self) -> np.ndarray:
        """(N,) bool source-episode successes."""
        return np.asarray(self._successes, dtype=bool)

    def state(self, index: int, state_type: type | None = None):
        """Entry ``index``'s state as a nested dict (or ``state_type(**fields)``)."""
        if not -len(self) <= index < len(self):
            raise IndexError(f"entry {index} of a buffer of {len(self)}")
        flat = {}
        for path, values in self._states.items():
            value, kind = values[index], self._schema[path]["kind"]
            flat[path] = np.array(value) if kind == "array" else {"str": str, "int": int, "float": float,
                                                                 "bool": bool}[kind](value.item())
        nested = _unflatten(flat)
        return state_type(**nested) if state_type is not None else nested

    def entry(self, index: int, state_type: type | None = None) -> TerminalEntry:
        return TerminalEntry(self.state(index, state_type), self._histories[index].copy(), self._returns[index],
                             self._successes[index])

    def sample(self, rng: np.random.Generator, state_type: type | None = None,
               successful_only: bool = False) -> TerminalEntry:
        """A uniformly drawn entry (among successful ones if ``successful_only``)."""
        candidates = np.flatnonzero(self.successes) if successful_only else np.arange(len(self))
        if len(candidates) == 0:
            what = "successful entries" if successful_only else "entries"
            raise ValueError(f"the {self.source_task} -> {self.target_task} terminal buffer has no {what}")
        return self.entry(int(rng.choice(candidates)), state_type)

    def _meta(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "source_task": self.source_task,
                "target_task": self.target_task, "scenario": self.scenario, "obs_spec": self.obs_spec.to_dict(),
                "history": self.history, "size": len(self), "schema": self._schema or {}}

    def save(self, path: str | os.PathLike) -> Path:
        """Atomically writes the buffer (a crash mid-write leaves any previous file intact); returns the path."""
        arrays = {"meta": np.asarray(json.dumps(self._meta())), "histories": self.histories,
                  "returns": self.returns, "successes": self.successes}
        for path_key, values in self._states.items():
            arrays[_STATE_PREFIX + path_key] = np.stack(values)
        return atomic_write(path, lambda file: np.savez(file, **arrays))

    @classmethod
    def load(cls, path: str | os.PathLike, expected_task: str | None = None, expected_obs_spec=None, *,
             expected_source: str | None = None, expected_scenario: str | None = None) -> "TerminalBuffer":
        """Reads a buffer written by :meth:`save`, checking what the caller expects.

        Args:
            expected_task: the target task about to start from the states.
            expected_obs_spec: the observation spec the caller's feasibility function reads.
            expected_source: the task that should have produced them (also named in the missing-file message).
            expected_scenario: the scenario they should belong to.

        Raises:
            FileNotFoundError: no file; the message names the command that makes it.
            ValueError: not a buffer, another format version, or a mismatched task, scenario or spec (the
                message gives both values).
        """
        path = Path(path)
        if not path.is_file():
            source = expected_source or "<source task>"
            raise FileNotFoundError(f"terminal buffer {path} does not exist; create it by rolling out the "
                                    f"previous sub-task's policy: seqdex collect --task {source}")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {key: data[key] for key in data.files}
            meta = json.loads(str(arrays.pop("meta")))
        except Exception as error:  # noqa: BLE001 - zipfile/numpy/json raise many types for damaged files.
            raise ValueError(f"{path} is not a readable terminal buffer ({type(error).__name__}: {error})") from error
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise ValueError(f"{path} is not a terminal buffer (no '{FORMAT}' format tag)")
        if meta.get("version") != VERSION:
            raise ValueError(f"terminal buffer {path} has format version {meta.get('version')}, this code reads "
                             f"version {VERSION}; collect it again with this code")
        for what, expected, found in (("target task", expected_task, meta["target_task"]),
                                      ("source task", expected_source, meta["source_task"]),
                                      ("scenario", expected_scenario, meta["scenario"])):
            if expected is not None and expected != found:
                raise ValueError(f"terminal buffer {path} has {what} {found!r}, but {expected!r} was expected")
        obs_spec = ObservationSpec.from_dict(meta["obs_spec"])
        obs_spec.check(expected_obs_spec, f"terminal buffer {path}")
        buffer = cls(meta["source_task"], meta["target_task"], meta["scenario"], obs_spec, meta["history"])
        size = int(meta["size"])
        histories, returns, successes = arrays["histories"], arrays["returns"], arrays["successes"]
        if not len(histories) == len(returns) == len(successes) == size:
            raise ValueError(f"terminal buffer {path} is inconsistent: {size} entries recorded, arrays of "
                             f"{len(histories)}/{len(returns)}/{len(successes)}")
        buffer._schema = meta["schema"] or None
        buffer._states = {p: list(arrays[_STATE_PREFIX + p]) for p in (buffer._schema or {})}
        buffer._histories = list(histories.astype(np.float32))
        buffer._returns = [float(r) for r in returns]
        buffer._successes = [bool(s) for s in successes]
        return buffer
