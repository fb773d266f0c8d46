"""Scenario loading: every shipped scenario loads typed; bad input gets a clear ScenarioError."""

import pytest
from pydrake.multibody.parsing import LoadModelDirectives, PackageMap

from seqdex_drake.scenario import (
    MODELS_DIR,
    MODELS_PACKAGE,
    DumpScenario,
    LoadScenario,
    Scenario,
    ScenarioError,
    ScenarioNames,
)

EXPECTED = {
    "building_blocks/search", "building_blocks/orient", "building_blocks/grasp", "building_blocks/insert",
    "tool_positioning/tool_grasp", "tool_positioning/tool_reorient",
    "building_blocks/chain",  # the whole Building Blocks task in one scene (scripts/simulate_chain.py)
    "handover/reach", "handover/lower",  # the cheap two-stage chain (benchmarks/chain_methods.py)
}


def test_every_subtask_has_a_named_scenario():
    assert set(ScenarioNames()) == EXPECTED


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_scenarios_load_typed(name):
    scenario = LoadScenario(name)
    assert isinstance(scenario, Scenario)
    assert scenario.subtask == name.split("/")[1]
    assert scenario.task_family == name.split("/")[0]
    assert scenario.plant_config.time_step > 0
    assert scenario.directives, "every scenario adds models"
    assert abs(scenario.control_period - 1 / 60) < 1e-12  # The paper's 60 Hz policy rate.


def test_bare_names_and_overrides():
    scenario = LoadScenario("grasp", scenario_text="{random_seed: 7, plant_config: {time_step: 0.001}}")
    assert scenario.random_seed == 7
    assert scenario.plant_config.time_step == 0.001
    assert scenario.plant_config.discrete_contact_approximation == "lagged"  # Untouched by the override.


def test_dump_round_trips():
    scenario = LoadScenario("building_blocks/search")
    text = DumpScenario(scenario)
    assert "top_down" in text and "block_*" in text


def test_every_directive_file_parses():
    package_map = PackageMap()
    package_map.Add(MODELS_PACKAGE, str(MODELS_DIR))
    for path in MODELS_DIR.glob("*.dmd.yaml"):
        directives = LoadModelDirectives(str(path)).directives
        assert directives, path
        for directive in directives:
            if directive.add_model is not None:
                assert package_map.ResolveUrl(directive.add_model.file), directive.add_model.file


@pytest.mark.parametrize("name, text, message", [
    ("no_such_task", "{}", "valid scenarios: building_blocks/search"),
    ("grasp", "{unknown_key: 1}", "unknown_key"),
    ("grasp", "{freeze: {bogus: 2}}", "bogus"),
    ("grasp", "{random_seed: [", "malformed YAML"),
    ("grasp", "{object_layout: heap}", "object_layout"),
    ("grasp", "{control_period: -1.0}", "control_period"),
])
def test_bad_input_names_the_problem(name, text, message):
    with pytest.raises(ScenarioError, match=message):
        LoadScenario(name, scenario_text=text)


def test_malformed_and_missing_files(tmp_path):
    bad = tmp_path / "bad.scenarios.yaml"
    bad.write_text("grasp: {subtask: [unclosed\n")
    with pytest.raises(ScenarioError, match="malformed YAML"):
        LoadScenario("grasp", filename=bad)
    with pytest.raises(ScenarioError, match="not found"):
        LoadScenario("grasp", filename=tmp_path / "missing.scenarios.yaml")
    unknown_key = tmp_path / "k.scenarios.yaml"
    unknown_key.write_text("grasp: {subtask: grasp, speling_mistake: 1}\n")
    with pytest.raises(ScenarioError, match="speling_mistake"):
        LoadScenario("grasp", filename=unknown_key)
