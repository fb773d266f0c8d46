"""The README's Python examples run as written (the embedding example with a shorter horizon), every one of them is
run by a test, and the README keeps its shape: the two set-up commands first, a short page."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
FIRST_COMMANDS = [
    "bash scripts/venv.sh python scripts/simulate_chain.py      # main job: a Building Blocks chain live in meshcat "
    "(URL printed)",
    "bash scripts/venv.sh python -m pytest -q                   # the tests",
]
#: The first line of each README python block and the test that runs it.
EXAMPLES = {
    "import gymnasium as gym": "test_readme.py::test_the_gymnasium_example_runs",
    "from pydrake.systems.analysis import Simulator": "test_readme.py::test_the_embedding_example_runs",
}


def _blocks(language: str = "python") -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README.read_text(), flags=re.DOTALL)


def _example(first_line: str) -> str:
    """The README's ```python block that starts with ``first_line``."""
    matches = [block for block in _blocks() if block.startswith(first_line)]
    assert len(matches) == 1, f"README has {len(matches)} python blocks starting with {first_line!r}"
    return matches[0]


def test_the_gymnasium_example_runs():
    namespace = {}
    exec(compile(_example("import gymnasium as gym"), "README.md", "exec"), namespace)
    env = namespace["env"]
    assert env.spec.id == "seqdex/ToolGrasp-v0" and env.spec.max_episode_steps == 150  # The comment's promise.
    assert namespace["observation"].shape == (159,) and namespace["action"].shape == (19,)
    assert "reward/closeness" in namespace["info"] and "success" in namespace["info"]
    restored, _ = env.reset(options={"initial_state": namespace["state"]})  # The comment's promise.
    assert (restored == env.unwrapped.observation()).all()
    env.close()


def test_the_embedding_example_runs(tmp_path, monkeypatch, capsys):
    code = _example("from pydrake.systems.analysis import Simulator")
    assert "simulator.AdvanceTo(10.0)" in code
    code = code.replace("simulator.AdvanceTo(10.0)", "simulator.AdvanceTo(0.25)")  # CI time: a few ticks.
    (tmp_path / "runs" / "chain").mkdir(parents=True)  # An empty run directory: every stage runs untrained.
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(code, "README.md", "exec"), namespace)
    assert "orient" in capsys.readouterr().out  # The missing policies are listed.
    context, chain = namespace["context"], namespace["chain"]
    assert context.get_time() == pytest.approx(0.25)
    assert int(chain.GetOutputPort("active_stage").Eval(chain.GetMyContextFromRoot(context))[0]) in (0, 1, 2)


def test_every_python_example_is_run_by_a_test():
    blocks = _blocks()
    first_lines = [block.splitlines()[0] for block in blocks]
    assert sorted(first_lines) == sorted(EXAMPLES), (
        "each README python block needs a test that runs it; add the new one's first line to EXAMPLES")
    tests = Path(__file__).resolve().parent
    for target in EXAMPLES.values():
        module, name = target.split("::")
        assert f"def {name}(" in (tests / module).read_text(), target


def test_the_readme_opens_with_the_two_commands_and_stays_short():
    first = _blocks("bash")[0].splitlines()
    assert first[:2] == FIRST_COMMANDS
    assert README.read_text().index("```bash") < README.read_text().index("```python")
    assert len(README.read_text().splitlines()) <= 150, "keep the README short; move details to docs/"
