"""Success-rate tables in the paper's layout (Table 1 / 2: one column per object, then trained / unseen / all),
written as markdown and CSV. Every cell is the mean +- standard deviation over seeds of the per-seed success
rate (population std; a single seed gives +- 0.00)."""

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np


def seed_rates(results: Sequence[dict], objects: Sequence) -> dict:
    """{object or group: per-seed success rates} from episode records ``{seed, object, success}``; groups are
    'trained', 'unseen' and 'all' (``objects`` entries are (key, label, trained))."""
    seeds = sorted({r["seed"] for r in results})
    rates: dict[str, list[float]] = {}
    groups = {"trained": [k for k, _, t in objects if t], "unseen": [k for k, _, t in objects if not t],
              "all": [k for k, _, _ in objects]}
    for key, _, _ in objects:
        rates[str(key)] = [_rate(results, seed, [key]) for seed in seeds]
    for group, keys in groups.items():
        rates[group] = [_rate(results, seed, keys) for seed in seeds]
    return rates


def _rate(results, seed, keys) -> float:
    outcomes = [r["success"] for r in results if r["seed"] == seed and r["object"] in keys]
    return float(np.mean(outcomes)) if outcomes else float("nan")


def cell(values: Sequence[float]) -> str:
    values = np.asarray([v for v in values if np.isfinite(v)], dtype=float)
    if values.size == 0:
        return "-"
    return f"{values.mean():.2f} ± {values.std():.2f}"


def write_table(path_stem: Path, title: str, row_names: Sequence[str], columns: Sequence[str],
                rows: Sequence[dict], notes: Sequence[str] = ()) -> tuple[Path, Path]:
    """Writes ``<stem>.md`` and ``<stem>.csv``: one row per entry of ``rows`` ({column: per-seed values}).

    The CSV has, per column, ``<column>_mean``, ``<column>_std`` and ``<column>_n`` (seeds)."""
    path_stem.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# {title}", "", "| | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for name, row in zip(row_names, rows, strict=True):
        lines.append(f"| {name} | " + " | ".join(cell(row.get(c, [])) for c in columns) + " |")
    lines += [""] + [f"- {note}" for note in notes]
    markdown = path_stem.with_suffix(".md")
    markdown.write_text("\n".join(lines).rstrip() + "\n")
    table = path_stem.with_suffix(".csv")
    with table.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["row"] + [f"{c}_{kind}" for c in columns for kind in ("mean", "std", "n")])
        for name, row in zip(row_names, rows, strict=True):
            out = [name]
            for column in columns:
                values = np.asarray([v for v in row.get(column, []) if np.isfinite(v)], dtype=float)
                out += [f"{values.mean():.4f}", f"{values.std():.4f}", values.size] if values.size else ["", "", 0]
            writer.writerow(out)
    return markdown, table
