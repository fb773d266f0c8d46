"""The README's Python examples run as written (the embedding example with a shorter horizon)."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _example(first_line: str) -> str:
    """The README's ```python block that starts with ``first_line``."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)
    matches = [block for block in blocks if block.startswith(first_line)]
    assert len(matches) == 1, f"README has {len(matches)} python blocks starting with {first_line!r}"
    return matches[0]


def test_the_sub_task_env_example_runs():
    namespace = {}
    exec(compile(_example("from seqdex_drake.tasks.registry import make_env"), "README.md", "exec"), namespace)
    assert namespace["observation"].shape == (159,) and "reward/closeness" in namespace["info"]
    env = namespace["env"]
    restored, _ = env.reset(options={"initial_state": namespace["state"]})  # The comment's promise.
    assert (restored == env.observation()).all()


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
