"""Runs every benchmark the docs quote, collects their figures into results/benchmarks.json and rewrites the table
of docs/performance.md (between its ``benchmarks-table`` marker comments) from that file.

    python benchmarks/run_all.py                          # every benchmark, real mode (~40 min; a quiet machine)
    python benchmarks/run_all.py --only chain_runtime osc_solve_time   # some; merged into results/benchmarks.json
    python benchmarks/run_all.py --table-only             # only rewrite the docs table from the JSON
    python benchmarks/run_all.py --test                   # each benchmark's own --test mode; checks that every
                                                          # figure of the table is printed (no timing meaning)

Each benchmark prints one JSON object as its last line (see each script's docstring); that object is stored whole
under ``benchmarks/<name>/result`` with the command, the commit and the date it ran at. :data:`FIGURES` names the
figures the table shows, as ``/``-separated key paths into those objects, with their goals. ``--test`` writes its
JSON to ``--out`` (default: a temporary file) and never touches results/ or docs/; it exits 1 if a benchmark
failed or a figure's key is missing from its output.
"""

import argparse
import dataclasses
import datetime
import json
import operator
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results" / "benchmarks.json"
DOC = ROOT / "docs" / "performance.md"
BEGIN, END = "<!-- benchmarks-table: begin (benchmarks/run_all.py writes this) -->", "<!-- benchmarks-table: end -->"


@dataclasses.dataclass(frozen=True)
class Benchmark:
    """One script under benchmarks/ and the arguments of its real and test runs."""

    name: str
    args: tuple[str, ...] = ()
    test_args: tuple[str, ...] = ("--test",)

    def command(self, test: bool = False) -> list[str]:
        return [f"benchmarks/{self.name}.py", *(self.test_args if test else self.args)]


@dataclasses.dataclass(frozen=True)
class Figure:
    """One row of the table: a value in a benchmark's last-line JSON."""

    what: str
    benchmark: str
    key: str
    """``/``-separated path into the benchmark's JSON object."""
    goal: str = ""
    """``>= 0.9``-style goal, or empty (a reference figure)."""


BENCHMARKS = [
    Benchmark("env_throughput"),
    Benchmark("env_instructions"),
    Benchmark("station_throughput"),
    Benchmark("search_settings"),
    Benchmark("train_throughput"),
    Benchmark("chain_runtime"),
    Benchmark("main_command_realtime"),
    Benchmark("osc_solve_time"),
    Benchmark("ray_throughput"),
    Benchmark("soak", args=("--minutes", "10")),
    Benchmark("handover_scripted", test_args=("--low", "0.125", "--high", "0.13")),  # No --test: two heights.
]

FIGURES = [
    Figure("env step / raw simulation rate, lowest of the paper's six sub-tasks", "env_throughput",
           "env_over_raw_min", ">= 0.90"),
    Figure("tool grasp env steps/s, one process", "env_throughput", "single_process/tool_grasp/env_steps_per_s"),
    Figure("grasp env steps/s, one process", "env_throughput", "single_process/grasp/env_steps_per_s"),
    Figure("search env steps/s, one process", "env_throughput", "single_process/search/env_steps_per_s"),
    Figure("2-worker speedup, grasp, 16 envs, grouped rollouts (as PPO steps)", "env_throughput",
           "two_worker_speedup", ">= 1.8"),
    Figure("2-worker speedup, the same with lock-step steps", "env_throughput", "two_worker_speedup_lockstep"),
    Figure("tool grasp env code: lines fetched beyond the L2 per step", "env_instructions",
           "per_step/tool_grasp/outside_l2_misses"),
    Figure("env code's share of a step's instructions, highest task", "env_instructions", "outside_max"),
    Figure("Search / Grasp env steps/s, random actions, interleaved (72-block pile)", "search_settings",
           "variants/shipped/search_env_over_grasp_env", ">= 0.25"),
    Figure("the same with Search's former settings (2 ms plant steps, default freezer)", "search_settings",
           "variants/former/search_env_over_grasp_env"),
    Figure("Search / Grasp station control-step rate, robot still (frozen far blocks)", "station_throughput",
           "search_over_grasp_ratio"),
    Figure("the same with every block dynamic", "station_throughput", "search_all_dynamic_over_grasp_ratio"),
    Figure("training / env steps/s, tool grasp, `--preset budget`", "train_throughput", "train_over_env", ">= 0.8"),
    Figure("training env steps/s, tool grasp, `--preset budget`", "train_throughput", "budget/train_steps_per_s"),
    Figure("learner (gradient steps) share of training time, budget", "train_throughput",
           "budget/learner_fraction"),
    Figure("training / env steps/s, tool grasp, `--preset paper`", "train_throughput", "paper/train_over_env"),
    Figure("chain tick, switcher + 4 policies computing (ms)", "chain_runtime", "tick_ms", "<= 1"),
    Figure("chain tick as the chain runs it, 1 policy computing (ms)", "chain_runtime", "tick_ms_chain", "<= 1"),
    Figure("chain tick, shipped tool-positioning networks (ms)", "chain_runtime", "tick_ms_shipped", "<= 1"),
    Figure("the same with F scored every tick (the paper's timing)", "chain_runtime", "tick_ms_shipped_every_tick"),
    Figure("memory floor of the 4-policy tick (ms)", "chain_runtime", "tick_floor_ms"),
    Figure("real-time factor, Grasp station + chain controller", "chain_runtime", "realtime_factor", ">= 1.0"),
    Figure("the same with Meshcat", "chain_runtime", "realtime_factor_meshcat", ">= 1.0"),
    Figure("real-time factor, station with constant targets", "chain_runtime", "station_realtime_factor"),
    Figure("real-time factor, main command, Building Blocks (shipped chain, first block), with Meshcat",
           "main_command_realtime", "building_blocks/realtime_factor_meshcat", ">= 1.0"),
    Figure("the same headless", "main_command_realtime", "building_blocks/realtime_factor"),
    Figure("real-time factor, main command, Tool Positioning (shipped chain, hammer), with Meshcat",
           "main_command_realtime", "tool_positioning/realtime_factor_meshcat", ">= 1.0"),
    Figure("the same headless", "main_command_realtime", "tool_positioning/realtime_factor"),
    Figure("OSC QP solve per 60 Hz tick, mean (ms)", "osc_solve_time", "osc_solve_ms_mean"),
    Figure("OSC QP solve per tick, 99th percentile (ms)", "osc_solve_time", "osc_solve_ms_p99"),
    Figure("OSC whole update per tick, mean (ms)", "osc_solve_time", "osc_update_ms_mean"),
    Figure("Ray / process vector env steps/s, grasp, 2 workers", "ray_throughput", "ray_over_process", ">= 0.9"),
    Figure("resident memory drift of a training soak, all processes (%)", "soak", "drift_percent/total", "< 5"),
    Figure("hand-over chain: straight-down Lower success from 12.5 cm", "handover_scripted", "band/0.125", ">= 1"),
    Figure("hand-over chain: straight-down Lower success from 13 cm", "handover_scripted", "band/0.130"),
]

_OPERATORS = {">=": operator.ge, "<=": operator.le, ">": operator.gt, "<": operator.lt}


def lookup(result: dict, key: str):
    """The value at ``key`` (``a/b/c``) in ``result``; KeyError naming the missing part."""
    value = result
    for part in key.split("/"):
        if not isinstance(value, dict) or part not in value:
            raise KeyError(f"{key}: no '{part}'")
        value = value[part]
    return value


def meets(value, goal: str) -> bool | None:
    """Whether ``value`` meets ``goal`` (``">= 0.9"``); None without a goal or a number."""
    match = re.fullmatch(r"\s*(>=|<=|>|<)\s*([-+0-9.eE]+)\s*", goal)
    if not match or not isinstance(value, int | float):
        return None
    return _OPERATORS[match.group(1)](value, float(match.group(2)))


def _format(value) -> str:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return "–" if value is None else str(value)
    return f"{value:.3g}" if abs(value) < 100 else f"{value:.0f}"


def table(results: dict) -> str:
    """The markdown table of :data:`FIGURES` with the values in ``results`` (a benchmarks.json object)."""
    commands = {b.name: "python " + " ".join(b.command()) for b in BENCHMARKS}
    lines = ["| Figure | Key (benchmark: JSON key) | Command | Value | Goal |", "|---|---|---|---|---|"]
    measured = {}
    for figure in FIGURES:
        entry = results.get("benchmarks", {}).get(figure.benchmark)
        value, shown = None, "to be measured"
        if entry is not None and entry.get("result") is not None:
            try:
                value = lookup(entry["result"], figure.key)
                shown = _format(value)
                measured[figure.benchmark] = entry
            except KeyError:
                shown = "not printed"
        met = meets(value, figure.goal) if figure.goal else None
        goal = figure.goal.replace(">=", "≥").replace("<=", "≤") if figure.goal else "–"
        if met is not None:
            goal += ": met" if met else ": not met"
        lines.append(f"| {figure.what} | `{figure.benchmark}: {figure.key}` | `{commands[figure.benchmark]}` "
                     f"| {shown} | {goal} |")
    runs = sorted({(entry["commit"], entry["date"][:10], entry.get("cpu_count")) for entry in measured.values()})
    lines.append("")
    if runs:
        lines.append("Measured at " + "; ".join(f"commit {commit}, {date}, {cores} cores" for commit, date, cores in
                                                runs) + " (`results/benchmarks.json`).")
    else:
        lines.append("Nothing measured yet: run `python benchmarks/run_all.py` (`results/benchmarks.json`).")
    return "\n".join(lines)


def write_table(results: dict, doc: Path = DOC) -> None:
    """Replaces the text between the marker comments of ``doc`` with :func:`table`."""
    text = doc.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{doc} lacks the marker comments {BEGIN!r} and {END!r}")
    head, rest = text.split(BEGIN, 1)
    doc.write_text(f"{head}{BEGIN}\n{table(results)}\n{END}{rest.split(END, 1)[1]}")


def commit() -> str:
    """The checked-out commit, ``+dirty`` when tracked files have uncommitted changes."""
    def git(*args):
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout.strip()

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "")


def run(benchmark: Benchmark, test: bool, timeout: float) -> dict:
    """Runs one benchmark, its output streamed; its record (the last line's JSON under ``result``)."""
    command = [sys.executable, *benchmark.command(test)]
    print(f"== {benchmark.name}: {' '.join(benchmark.command(test))}", flush=True)
    started, start = datetime.datetime.now().astimezone().isoformat(timespec="seconds"), time.monotonic()
    last, stderr = "", tempfile.TemporaryFile("w+")
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=stderr, text=True)
    watchdog = threading.Timer(timeout, process.kill)  # A hung benchmark is killed and reported as failed.
    watchdog.start()
    try:
        for line in process.stdout:
            print(f"   {line.rstrip()}", flush=True)
            last = line.strip() or last
        process.wait()
    finally:
        watchdog.cancel()
    record = {"command": "python " + " ".join(benchmark.command(test)), "date": started, "commit": commit(),
              "cpu_count": os.cpu_count(), "load_average_1min": round(os.getloadavg()[0], 2),
              "seconds": round(time.monotonic() - start, 1), "exit_code": process.returncode, "result": None}
    try:
        record["result"] = json.loads(last) if process.returncode == 0 else None
    except json.JSONDecodeError:
        pass
    if record["result"] is None:
        stderr.seek(0)
        record["error"] = (stderr.read()[-3000:] or last)
        print(f"   FAILED (exit {process.returncode}): {record['error'][-600:]}", flush=True)
    return record


def missing_keys(results: dict, names: list[str]) -> list[str]:
    """The figures of benchmarks ``names`` whose key is not in their result."""
    missing = []
    for figure in FIGURES:
        if figure.benchmark not in names:
            continue
        result = results["benchmarks"].get(figure.benchmark, {}).get("result")
        try:
            lookup(result or {}, figure.key)
        except KeyError as error:
            missing.append(f"{figure.benchmark}: {error.args[0]}")
    return missing


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    names = [b.name for b in BENCHMARKS]
    parser.add_argument("--only", nargs="+", choices=names, metavar="NAME", help=f"run these: {', '.join(names)}")
    parser.add_argument("--test", action="store_true", help="each benchmark's --test; results to --out only")
    parser.add_argument("--table-only", action="store_true", help="rewrite the docs table from --out, run nothing")
    parser.add_argument("--out", help="the JSON file (default: results/benchmarks.json; with --test a temp file)")
    parser.add_argument("--timeout", type=float, default=None, help="seconds per benchmark (7200; --test 900)")
    args = parser.parse_args(argv)
    out = Path(args.out) if args.out else (Path(tempfile.mkdtemp()) / "benchmarks.json" if args.test else RESULTS)
    if args.table_only:
        write_table(json.loads(out.read_text()) if out.exists() else {"benchmarks": {}})
        print(f"rewrote the table of {DOC} from {out}")
        return 0
    selected = [b for b in BENCHMARKS if args.only is None or b.name in args.only]
    results = json.loads(out.read_text()) if out.exists() and not args.test else {"benchmarks": {}}
    timeout = args.timeout or (900.0 if args.test else 7200.0)
    for benchmark in selected:
        results["benchmarks"][benchmark.name] = run(benchmark, args.test, timeout)
        results.update(commit=commit(), date=datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
                       mode="test" if args.test else "real")
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(results, indent=1) + "\n")  # After each: an interrupted run keeps what it has.
    failed = [b.name for b in selected if results["benchmarks"][b.name]["result"] is None]
    missing = missing_keys(results, [b.name for b in selected if b.name not in failed])
    print(f"wrote {out}")
    if not args.test:
        write_table(results)
        print(f"rewrote the table of {DOC}")
    for line in [f"failed: {name}" for name in failed] + [f"figure not printed: {key}" for key in missing]:
        print(line)
    return 1 if failed or missing else 0


if __name__ == "__main__":
    sys.exit(main())
