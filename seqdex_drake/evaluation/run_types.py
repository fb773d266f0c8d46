"""What a chain run (``evaluation/runner.ChainRunner``) is built from, what one object's episode returns, and the
error a run that cannot start raises."""

import dataclasses

import yaml


class ChainRunError(ValueError):
    """A chain run that cannot start (bad checkpoint, unknown object, ...); the message says what to fix."""


@dataclasses.dataclass
class RunConfig:
    """What :class:`ChainRunner` builds."""

    family: str = "building_blocks"
    """``building_blocks`` or ``tool_positioning``."""
    chain: str = ""
    """The chain to run (``diagrams/chains.yaml``); "": the family's own. E.g. ``building_blocks_policies``, the
    Building Blocks chain without the scripted retrieve, as the experiments that measured it ran."""
    run_dir: str | None = None
    """Chain run directory (``stages/<task>/best.pt|last.pt``, ``feasibility/<task>.pt``); None: all untrained."""
    max_switches: int = 3
    """Most feasibility switches per object (paper: 3 in simulation)."""
    stage_steps: tuple[int, ...] | None = None
    """Per-stage step budgets; None: each task's episode length."""
    history: int | None = None
    """Use the history-ablation F files ``feasibility/<task>_h<H>.pt`` instead of ``<task>.pt``."""
    seed: int = 0
    """Scenario seed (pile choice) and untrained-policy seed."""
    untrained_hidden_sizes: tuple[int, ...] | None = None
    """Hidden sizes of untrained policies (None: the paper's)."""
    trigger: str = ""
    """When the switcher scores the next stages between decisions (``SwitcherParams.trigger``: "next", the paper's
    c^{i+1} > 1 every tick; "any_later"; "decision", only at a stage's end); "": the family's
    (``chain_settings.SWITCH_TRIGGER``)."""
    refetches: int = 0
    """With a retrieve stage in the chain: the most other blocks of the same type fetched, one after another, when
    the retrieve ends with the target still in the pile (``evaluation/refetch.py``); 0 (the default, as the main
    command's recorded figures were measured): the first block only."""
    scenario_overrides: str = ""
    """YAML mapping applied on top of the family's chain scenario (``diagrams/<family>.scenarios.yaml``), e.g.
    ``"{plant_config: {time_step: 0.004}}"``: to measure a physics variant (``benchmarks/main_command_realtime.py
    --scenario-overrides``). The shipped policies were trained and every record was measured without one."""


def scenario_text(config: RunConfig) -> str:
    """The YAML the run's scenario is loaded with: ``config.scenario_overrides`` plus ``random_seed: config.seed``.

    Raises:
        ChainRunError: overrides that are not a YAML mapping, or that set ``random_seed`` (use ``seed``).
    """
    try:
        overrides = yaml.safe_load(config.scenario_overrides or "{}")
    except yaml.YAMLError as error:
        raise ChainRunError(f"scenario_overrides is not valid YAML ({error}); give a mapping such as "
                            "'{plant_config: {time_step: 0.004}}'") from error
    if not isinstance(overrides, dict):
        raise ChainRunError(f"scenario_overrides must be a YAML mapping such as '{{plant_config: {{time_step: "
                            f"0.004}}}}', got {config.scenario_overrides!r}")
    if "random_seed" in overrides:
        raise ChainRunError("scenario_overrides sets random_seed: set the run's seed instead (RunConfig.seed, --seed)")
    return yaml.safe_dump({**overrides, "random_seed": config.seed}, default_flow_style=True, width=1 << 16)


@dataclasses.dataclass
class Outcome:
    """The result of one object's episode."""

    success: bool
    time: float
    """Simulated seconds from the start of the episode."""
    last_stage: int
    switches: int
    position_error: float
    rotation_error: float
    simulator_error: str = ""
    """Why the simulation failed (a failed episode, as the envs truncate one); empty if it did not."""
    fell: bool = False
    """The target object fell off the table (below ``FELL_BELOW``), which ended the episode, failed."""
    refetches: int = 0
    """Other blocks of the type fetched after the retrieve left one in the pile (``RunConfig.refetches``)."""
