"""Paired comparisons of evaluation rows: the same episodes played by two chains, told apart by McNemar's test.

Every ``seqdex evaluate`` row seeds its episodes by (seed, object, episode), so two rows over the same seeds,
objects and episode counts play the same starts; the main command's records (``experiments/main_command_seeds.py``)
are one chain per seed, a block per manual step. :func:`load_outcomes` reads a row's ``episodes.jsonl`` (the main
experiment's records) as ``{(seed, object, episode): success}``, or a main-command record as
``{(seed, manual step, 0): placed}``; :func:`compare` pairs two rows on the episodes
both played and counts the four cells; the exact two-sided McNemar test (:func:`mcnemar_p`) asks whether the
discordant pairs (one row succeeds, the other fails) split unevenly beyond chance. :func:`paired_table` writes the
comparisons as a Markdown table (``scripts/paired_table.py``).
"""

import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path

#: The experiment whose records a row's comparisons use (``seqdex evaluate`` also records ablations).
MAIN_EXPERIMENT = "main"


def load_outcomes(row: str | Path) -> dict[tuple[int, int, int], bool]:
    """``{(seed, object, episode): success}`` of the main experiment's records in ``row`` (an evaluation output
    directory, or its ``episodes.jsonl``), or ``{(seed, manual step, 0): placed}`` of a main-command record (a
    ``.json`` file written by ``experiments/main_command_seeds.py``), or ``{(seed, 0, 0): success}`` of ``seqdex
    rollout --out`` records (``.json``; episode i of a record played seed + i). Several files joined by commas make
    one row. Raises ValueError for a row without records or with a record that lacks a field, and FileNotFoundError
    for a missing file, each naming the file."""
    if isinstance(row, str) and "," in row:
        merged = {}
        for part in row.split(","):
            merged.update(load_outcomes(part))
        return merged
    path = Path(row)
    path = path / "episodes.jsonl" if path.is_dir() else path
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file; give a seqdex evaluate output directory (--out) or a "
                                f"main_command_seeds.py record (--out)")
    if path.suffix == ".json":
        return _json_outcomes(path)
    outcomes = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            if record.get("experiment", MAIN_EXPERIMENT) != MAIN_EXPERIMENT:
                continue
            outcomes[(int(record["seed"]), int(record["object"]), int(record["episode"]))] = bool(record["success"])
        except (ValueError, KeyError, TypeError) as error:
            raise ValueError(f"{path}:{number}: not an episode record ({error})") from error
    if not outcomes:
        raise ValueError(f"{path} holds no episode of the main experiment")
    return outcomes


def _json_outcomes(path: Path) -> dict[tuple[int, int, int], bool]:
    """``{(seed, manual step, 0): placed}`` of a ``main_command_seeds.py`` record, or ``{(seed, 0, 0): success}``
    of a ``seqdex rollout`` record (its ``per_episode``)."""
    try:
        record = json.loads(path.read_text())
        if "per_episode" in record:
            return {(int(episode["seed"]), 0, 0): bool(episode["success"]) for episode in record["per_episode"]}
        rows = record["per_block"]
        outcomes = {(int(row["seed"]), int(row["step"]), 0): bool(row["placed"]) for row in rows}
    except (ValueError, KeyError, TypeError) as error:
        raise ValueError(f"{path}: not a main_command_seeds.py or seqdex rollout record ({error!r})") from error
    if not outcomes:
        raise ValueError(f"{path} holds no block")
    return outcomes


def mcnemar_p(only_first: int, only_second: int) -> float:
    """The exact two-sided McNemar p-value of ``only_first`` against ``only_second`` discordant pairs: twice the
    smaller binomial tail of Binomial(n, 1/2), n their sum, capped at 1 (1 when there is no discordant pair)."""
    if only_first < 0 or only_second < 0:
        raise ValueError(f"discordant counts must be >= 0, got {only_first} and {only_second}")
    n, k = only_first + only_second, min(only_first, only_second)
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


@dataclasses.dataclass(frozen=True)
class Comparison:
    """Two rows over the episodes both played."""

    first: str
    second: str
    episodes: int
    """Episodes both rows played (the pairs)."""
    first_successes: int
    second_successes: int
    both: int
    only_first: int
    only_second: int

    @property
    def p(self) -> float:
        """The exact two-sided McNemar p-value of the discordant pairs."""
        return mcnemar_p(self.only_first, self.only_second)


def compare(first: str, first_outcomes: dict, second: str, second_outcomes: dict) -> Comparison:
    """Pairs two rows' outcomes on the episodes both played; ValueError if they share none."""
    shared = sorted(first_outcomes.keys() & second_outcomes.keys())
    if not shared:
        raise ValueError(f"{first} and {second} share no episode (seed, object, episode): evaluate both with the "
                         f"same --seed, --seeds, --episodes and --objects")
    a = [first_outcomes[key] for key in shared]
    b = [second_outcomes[key] for key in shared]
    return Comparison(first, second, len(shared), sum(a), sum(b), sum(x and y for x, y in zip(a, b, strict=True)),
                      sum(x and not y for x, y in zip(a, b, strict=True)),
                      sum(y and not x for x, y in zip(a, b, strict=True)))


def paired_table(pairs: Sequence[tuple[str, str]], rows: dict[str, str | Path]) -> str:
    """A Markdown table of the comparisons ``pairs`` (names of ``rows``: name -> evaluation output directory)."""
    outcomes = {name: load_outcomes(path) for name, path in rows.items()}
    lines = ["| Comparison | Episodes | Successes | Both succeed | Only the first | Only the second | McNemar p |",
             "|---|---|---|---|---|---|---|"]
    for first, second in pairs:
        for name in (first, second):
            if name not in rows:
                raise ValueError(f"no row named {name!r}; rows: {', '.join(rows)}")
        c = compare(first, outcomes[first], second, outcomes[second])
        lines.append(f"| {first} vs {second} | {c.episodes} | {c.first_successes} / {c.second_successes} | {c.both} "
                     f"| {c.only_first} | {c.only_second} | {c.p:.3g} |")
    return "\n".join(lines) + "\n"
