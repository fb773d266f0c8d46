"""docs/ and the README stay true to the code: the performance table names only figures the benchmarks still print
and is what ``benchmarks/run_all.py`` writes; commands name scripts and flags that exist; links and paths resolve;
the picture's script runs."""

import functools
import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [ROOT / "README.md", *DOCS]
PERFORMANCE = ROOT / "docs" / "performance.md"


def _run_all():
    spec = importlib.util.spec_from_file_location("run_all", ROOT / "benchmarks" / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _table_keys() -> list[tuple[str, str]]:
    """(benchmark, key) of every row of docs/performance.md's table."""
    run_all = _run_all()
    text = PERFORMANCE.read_text()
    table = text[text.index(run_all.BEGIN):text.index(run_all.END)]
    keys = re.findall(r"^\|[^|]*\| `(\w+): ([^`]+)` \|", table, flags=re.MULTILINE)
    assert keys, "docs/performance.md's table names no benchmark keys"
    return keys


def test_the_performance_table_is_what_run_all_writes():
    run_all = _run_all()
    results = json.loads(run_all.RESULTS.read_text()) if run_all.RESULTS.exists() else {"benchmarks": {}}
    text = PERFORMANCE.read_text()
    written = text[text.index(run_all.BEGIN) + len(run_all.BEGIN):text.index(run_all.END)].strip()
    assert written == run_all.table(results), "regenerate it: python benchmarks/run_all.py --table-only"
    assert _table_keys() == [(figure.benchmark, figure.key) for figure in run_all.FIGURES]


def test_run_all_finds_a_key_that_is_not_printed():
    run_all = _run_all()
    results = {"benchmarks": {"osc_solve_time": {"result": {"osc_solve_ms_mean": 0.1}}}}
    missing = run_all.missing_keys(results, ["osc_solve_time"])
    assert missing == ["osc_solve_time: osc_solve_ms_p99: no 'osc_solve_ms_p99'",
                       "osc_solve_time: osc_update_ms_mean: no 'osc_update_ms_mean'"]
    assert run_all.lookup({"a": {"b": 2}}, "a/b") == 2 and run_all.meets(0.95, ">= 0.9") and not run_all.meets(6, "< 5")


@pytest.mark.parametrize("benchmark", sorted({benchmark for benchmark, _ in _table_keys()}))
def test_every_key_the_docs_table_names_is_printed_by_its_benchmark(benchmark, benchmark_run):
    """Each benchmark of the docs table, in its quick mode as run_all.py --test runs it, prints every key the table
    names for it. The run is the session's one run of that benchmark (conftest.py), which tests/test_benchmarks.py
    checks too."""
    record = benchmark_run(benchmark)
    assert record["result"] is not None, f"{record['command']} failed in --test mode: {record.get('error', '')[-3000:]}"
    run_all, missing = _run_all(), []
    for name, key in _table_keys():
        if name == benchmark:
            try:
                run_all.lookup(record["result"], key)
            except KeyError as error:
                missing.append(error.args[0])
    assert not missing, f"docs/performance.md names keys {benchmark} no longer prints: {missing}"


# ------------------------------------------------------------------------------------------ commands, links, paths
@functools.cache
def _seqdex_flags() -> dict[str, set[str]]:
    from seqdex_drake.cli.main import build_parser

    parser = build_parser()
    commands = next(action for action in parser._actions if action.choices and hasattr(action, "_name_parser_map"))
    return {name: {option for action in sub._actions for option in action.option_strings}
            for name, sub in commands.choices.items()}


def _script_flags(path: Path) -> set[str]:
    """The flags of a script: its own ``add_argument`` calls, or those of the ``seqdex`` subcommand it is the thin
    entry of (``main(["simulate", *sys.argv[1:]])``)."""
    text = path.read_text()
    entry = re.search(r"main\(\[\"(\w+)\", \*sys\.argv\[1:\]\]\)", text)
    if entry:
        return _seqdex_flags()[entry.group(1)] | {"--help"}
    return set(re.findall(r"add_argument\(\s*\"(--[\w-]+)\"", text)) | {"--help"}


def _commands(page: Path) -> list[str]:
    """The ``seqdex ...`` and ``python scripts|benchmarks|experiments/...`` commands of a page: bash block lines and
    inline code."""
    text = page.read_text()
    lines = [line for block in re.findall(r"```bash\n(.*?)```", text, flags=re.DOTALL) for line in block.splitlines()]
    prose = re.sub(r"```.*?```", "", text, flags=re.DOTALL)
    lines += [" ".join(span.split()) for span in re.findall(r"`([^`]+)`", prose)]
    commands = []
    for line in lines:
        line = line.split("#", 1)[0].replace("bash scripts/venv.sh ", "").strip()
        if re.match(r"(seqdex \w|python (scripts|benchmarks|experiments)/)", line):
            commands.append(line)
    return commands


@pytest.mark.parametrize("page", PAGES, ids=lambda page: page.name)
def test_commands_name_existing_scripts_subcommands_and_flags(page):
    commands = _commands(page)
    assert page.name != "README.md" or len(commands) >= 10
    problems = []
    for command in commands:
        words = command.split()
        flags = {word.split("=")[0] for word in re.findall(r"(?<![\w-])--[a-z][\w-]*", command)}
        if words[0] == "seqdex":
            known = _seqdex_flags().get(words[1])
            if known is None:
                problems.append(f"{command}: no subcommand '{words[1]}'")
                continue
        else:
            script = ROOT / words[1]
            if not script.is_file():
                problems.append(f"{command}: no {words[1]}")
                continue
            known = _script_flags(script)
        problems += [f"{command}: no flag {flag}" for flag in sorted(flags - known)]
    # A flag named alone in the prose (`--preset budget`) must be a flag of the seqdex command or of some script.
    folders = ("scripts", "benchmarks", "experiments")
    every = set().union(*_seqdex_flags().values(), *(_script_flags(path) for folder in folders
                                                     for path in (ROOT / folder).glob("*.py")))
    prose = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
    alone = {span.split()[0].split("=")[0] for span in re.findall(r"`(--[a-z][^`]*)`", prose)}
    problems += [f"no command or script has a flag {flag}" for flag in sorted(alone - every)]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("page", PAGES, ids=lambda page: page.name)
def test_links_and_repository_paths_resolve(page):
    text = page.read_text()
    problems = []
    for target in re.findall(r"\]\(([^)]+)\)", text):
        if target.startswith("http"):
            continue
        path = target.split("#", 1)[0]
        if path and not (page.parent / path).exists():
            problems.append(f"link {target}")
    prose = re.sub(r"```.*?```", "", text, flags=re.DOTALL)
    for span in re.findall(r"`([^`\s]+)`", prose):
        if ("/" not in span or any(c in span for c in "<>()\"'=") or span.startswith(("runs/", "demos/", "/", "..."))
                or not re.search(r"\.(py|md|yaml|c|png)$", span)):
            continue
        span = span.split(":")[0]
        if not any(list(base.glob(span)) for base in (ROOT, ROOT / "seqdex_drake")):
            problems.append(f"path {span}")
    assert not problems, f"{page.name}: " + ", ".join(problems)


def test_the_scene_picture_script_runs():
    assert (ROOT / "docs" / "images" / "scene.png").is_file()
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "render_scene.py"), "--test"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    assert "distinct colours" in done.stdout
