"""The feasibility-based policy switcher (paper Sec. 3.3) as a Drake LeafSystem.

Stages are indexed 0..K-1 in chain order (the paper's stage k is index k-1). ``feasibility[i]`` (i >= 1) is
the paper's F^{i+1}: it scores the last H observations *in stage i-1's layout* and predicts stage i's
return; its score is c^i = F^i(history) / h^i. Stage 0 never has one.

Every control tick the switcher appends each needed observation to a history kept as discrete state (the last
H observations per stage layout; shorter histories are left-padded by ``pad_history`` inside the model),
computes the scores its trigger needs and advances the executing stage's step counter. As the paper describes
it, only the next stage's score c^{i+1} is computed every tick (``SwitcherParams.trigger = "next"``); with
``trigger = "any_later"`` every later stage's is; with ``trigger = "decision"`` none is (the scores are computed
only at the other decisions below, so a stage is never cut short by a score). A *decision* happens when

- a computed later score exceeds 1 (the paper's switch timing: c^{i+1} > 1), or
- the executing stage's step budget is used up, or the optional ``stage_success`` input is above 0.5, or the
  optional ``stage_done`` (a scripted stage's policy system says its script is finished), or
- every tick, with ``evaluate_every_tick`` (every score every tick).

At a decision, while fewer than ``max_switches`` feasibility switches have been made, the switcher computes every
c^i from the same histories, walks back from the last stage and selects the first stage with c > 1; if none has,
it restarts from stage 0. Output ``feasibility_scores`` holds each c^i as last computed (NaN where a stage has no
F, or before its first computation). This is a
feasibility switch: it counts one towards ``max_switches`` and restarts the selected stage's budget (with
``evaluate_every_tick`` only a change of stage counts). Two selections do not switch (the sequential rule applies
instead): the last stage selecting itself at its budget's end (it is not restarted: the chain is done), and a stage
flagged in ``SwitcherParams.free_object_stages`` while the object is held. Otherwise -- the cap is reached,
``max_switches = 0``, or the stage after the current one has no F (for the last stage: its own F; an untrained
pipeline: the transition cannot be judged) -- the *sequential rule* applies: on budget or success the chain
advances to the next stage; the last stage keeps running. ``max_switches = 0`` is thus plain sequential execution with
per-stage time budgets (Policy-Seq).

While the optional ``approach_active`` input is above 0.5 (the operational-space controller moves the hand,
no policy acts) the step counter does not run and no decision is taken; histories and scores still update.

Inference. By default (``SwitcherParams.inference = "numpy"``) the torch F's (attention or MLP) are evaluated
from a :class:`~seqdex_drake.controller.inference.FeasibilityBank` (float32 numpy copies of their weights, equal to
the torch forward pass to ~1e-6 relative, rebuilt when a model's tensors change in place; F's of one
architecture run as one batched pass per tick); other F objects (e.g. a hand-written scorer with ``predict``)
and ``inference = "torch"`` go through :func:`feasibility_score`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch
from pydrake.systems.framework import BasicVector, Context, DiscreteValues, LeafSystem

from seqdex_drake.chaining.feasibility import pad_history, score, walk_back
from seqdex_drake.controller.inference import FeasibilityBank, snapshot_feasibility

_STAGE, _STEPS, _SWITCHES = 0, 1, 2
#: ``SwitcherParams.trigger``'s values.
TRIGGERS = ("next", "any_later", "decision")


def feasibility_score(f, history: np.ndarray) -> float:
    """c = F(history) / h for one (T, obs_dim) history. A feasibility model in eval mode runs directly under
    ``torch.inference_mode`` (what ``score`` computes, without its per-call train/eval toggling, which cost
    about as much as the forward pass); anything else goes through ``chaining.feasibility.score``."""
    model = f.model
    if isinstance(model, torch.nn.Module) and hasattr(model, "forward_normalized") and not model.training:
        batch = pad_history(np.asarray(history, dtype=np.float32)[None], int(f.config.input_length))
        with torch.inference_mode():
            value = float(model(torch.as_tensor(batch, device=model.obs_mean.device))[0])
        return value / float(f.threshold)
    return float(score(model, history, f.threshold))


@dataclasses.dataclass
class SwitcherParams:
    """Parameters of :class:`FeasibilitySwitcher`."""

    max_switches: int = 3
    """Most feasibility switches per run (paper Fig. 5a: 0-3 in simulation, 10 in the real world); 0 =
    sequential execution."""
    stage_steps: tuple[int, ...] | None = None
    """Step budget (control ticks) per stage; None: each task's ``TaskConfig.episode_length``."""
    evaluate_every_tick: bool = False
    """Walk the scores every tick (a change of stage counts as a switch) instead of at decision points."""
    trigger: str = "next"
    """Scores computed every tick between decisions: "next" (c^{i+1} only, the paper's switch timing) or
    "any_later" (every later stage's, so a later stage becoming feasible also triggers a decision; costs one F
    per later stage per tick) or "decision" (none: the walk back runs only at a stage's end -- its budget, success
    or ``stage_done`` -- so no score hands over in the middle of a stage; switches then retry, recover or skip only
    where a stage ends)."""
    inference: str = "numpy"
    """"numpy": evaluate torch F's from float32 numpy snapshots (fast at batch 1); "torch": the models themselves."""
    time_steps: tuple[int, ...] | None = None
    """Per stage, the episode length of a stage whose policy observes its progress (``TaskConfig.observe_time``;
    0: none). Its F^{i+1} was fitted on env observations that end with that progress, so the switcher appends
    it to the stage's history rows: ticks in the stage / time_steps while the stage executes (as the env's step
    count), 1 once another stage executes (the stage is over). None: no stage observes its progress."""
    approach_on_entry: tuple[bool, ...] | None = None
    """Per stage, whether entering it (in sequence or by a feasibility switch) restarts the approach (output
    ``stage_epoch`` changes): the hand is brought back to the hover point its policy's resets start from. A switch
    back to the executing or an earlier stage always restarts it; a switch forward into an unflagged stage does
    not (it starts where the hand is, as forward initialization hands it over). None: no stage's."""
    free_object_stages: tuple[bool, ...] | None = None
    """Per stage, whether a feasibility switch may select it only while the target object is free (input
    ``object_held`` at most 0.5). Tool Grasp starts with the tool on the table: a switch back to it with the tool
    still in the fist (the policy cannot put it down) made the approach chase the held tool off the workspace. A
    switch that would select such a stage then does not happen and the sequential rule applies; a dropped tool is
    free, so F sending the chain back for it still switches. None: no stage's."""


class FeasibilitySwitcher(LeafSystem):
    """Chooses the executing stage from the feasibility scores c^i = F^i / h^i (see the module docstring).

    Input ports: ``observation.<i>`` for every stage i whose successor has an F (stage i's observation, the
    history F^{i+1} reads), ``stage_success`` (1, optional), ``stage_done`` (1, optional: as ``stage_success``, from
    the executing scripted stage), ``approach_active`` (1, optional), ``object_held``
    (1, optional: ``SwitcherParams.free_object_stages``).
    Output ports: ``active_stage`` (1, the stage index 0..K-1 to execute), ``feasibility_scores`` (K, c^i;
    NaN for stage 0 and stages without F), ``switches_used`` (1), ``stage_epoch`` (1: changes whenever a stage
    starts from the hover point: entering a stage flagged in ``SwitcherParams.approach_on_entry``, or a feasibility
    switch back to the executing or an earlier stage; feed it to the approach controller's ``stage_epoch``).

    Args:
        feasibility: K entries; entry 0 must be None, entry i is None (no F) or an object with ``model``
            (its ``predict`` takes a (T, obs_dim) history), ``threshold`` (h) and ``config.input_length``
            (H), e.g. a :class:`~seqdex_drake.chaining.feasibility_io.FeasibilityFile`.
        observation_sizes: K observation sizes, one per stage (stage i-1's size is F^i's input size).
        stage_steps: K step budgets (control ticks); ``params.stage_steps`` overrides them when given.
        control_period: seconds between updates (the scenario's ``control_period``).
        params: switch cap and decision rule; defaults to ``SwitcherParams()``.
    """

    def __init__(self, feasibility: Sequence, observation_sizes: Sequence[int], stage_steps: Sequence[int],
                 control_period: float, params: SwitcherParams | None = None):
        super().__init__()
        self._params = params = params or SwitcherParams()
        self._feasibility = list(feasibility)
        count = self.num_stages = len(self._feasibility)
        budgets = list(params.stage_steps if params.stage_steps is not None else stage_steps)
        if count < 1 or len(observation_sizes) != count or len(budgets) != count:
            raise ValueError(f"need one F entry, observation size and step budget per stage; got {count}, "
                             f"{len(observation_sizes)} and {len(budgets)}")
        if self._feasibility[0] is not None:
            raise ValueError("stage 0 has no predecessor, so it cannot have a feasibility function; pass None")
        if min(budgets) < 1:
            raise ValueError(f"every stage step budget must be at least 1 tick, got {budgets}")
        if params.max_switches < 0:
            raise ValueError(f"max_switches must be >= 0, got {params.max_switches}")
        if params.trigger not in TRIGGERS:
            raise ValueError(f"trigger must be one of {', '.join(map(repr, TRIGGERS))}, got {params.trigger!r}")
        if params.inference not in ("numpy", "torch"):
            raise ValueError(f"inference must be 'numpy' or 'torch', got {params.inference!r}")
        self._budgets = np.asarray(budgets, dtype=int)
        entry = [False] * count if params.approach_on_entry is None else [bool(e) for e in params.approach_on_entry]
        if len(entry) != count:
            raise ValueError(f"approach_on_entry needs one flag per stage ({count}), got {params.approach_on_entry}")
        self._approach_on_entry = entry
        free = [False] * count if params.free_object_stages is None else [bool(f) for f in params.free_object_stages]
        if len(free) != count:
            raise ValueError(f"free_object_stages needs one flag per stage ({count}), got {params.free_object_stages}")
        self._free_object = free
        self._time_steps = [0] * count if params.time_steps is None else [int(t) for t in params.time_steps]
        if len(self._time_steps) != count or min(self._time_steps) < 0:
            raise ValueError(f"time_steps needs one entry >= 0 per stage ({count}), got {params.time_steps}")
        self._history_ports, self._history_index, self._history_shape = {}, {}, {}
        self._bank, self._bank_stages = None, []  # The torch F's as numpy snapshots (inference = "numpy").
        for stage in range(1, count):
            f = self._feasibility[stage]
            if f is None:
                continue
            source, size = stage - 1, int(observation_sizes[stage - 1])
            timed = 1 if self._time_steps[source] else 0  # The progress entry the switcher appends.
            model_dim = getattr(f.model, "obs_dim", size + timed)
            if model_dim != size + timed:
                raise ValueError(f"the feasibility function of stage {stage} reads {model_dim}-dim histories, but "
                                 f"stage {source}'s observation has {size + timed}"
                                 f"{' (its progress included)' if timed else ''}; use the F trained on that stage")
            if isinstance(f.model, torch.nn.Module):
                f.model.eval()  # Inference only (no dropout).
            if params.inference == "numpy" and snapshot_feasibility(f.model) is not None:
                self._bank_stages.append(stage)
            length = int(f.config.input_length)
            self._history_shape[source] = (length, size + timed)
            self._history_ports[source] = self.DeclareVectorInputPort(f"observation.{source}", size)
            self._history_index[source] = self.DeclareDiscreteState(np.zeros(1 + length * (size + timed)))
        self._build_bank()
        self._success_port = self.DeclareVectorInputPort("stage_success", 1)
        self._done_port = self.DeclareVectorInputPort("stage_done", 1)
        self._approach_port = self.DeclareVectorInputPort("approach_active", 1)
        self._held_port = self.DeclareVectorInputPort("object_held", 1)
        self._status_index = self.DeclareDiscreteState(np.zeros(3))  # stage, steps in stage, switches used
        self._scores_index = self.DeclareDiscreteState(np.full(count, np.nan))
        self._entries_index = self.DeclareDiscreteState(np.zeros(1))  # Stage starts with the approach (stage_epoch).
        status = {self.discrete_state_ticket(self._status_index)}
        self.DeclareVectorOutputPort("active_stage", 1, self._calc_stage, prerequisites_of_calc=status)
        self.DeclareStateOutputPort("feasibility_scores", self._scores_index)
        self.DeclareVectorOutputPort("switches_used", 1, self._calc_switches, prerequisites_of_calc=status)
        self.DeclareVectorOutputPort("stage_epoch", 1, self._calc_epoch,
                                     prerequisites_of_calc=status | {self.discrete_state_ticket(self._entries_index)})
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(control_period, 0.0, self._update)

    @property
    def params(self) -> SwitcherParams:
        return self._params

    @property
    def stage_budgets(self) -> np.ndarray:
        return self._budgets.copy()

    def has_feasibility(self, stage: int) -> bool:
        return 0 <= stage < self.num_stages and self._feasibility[stage] is not None

    # ------------------------------------------------------------------------------------------ history
    def history(self, context: Context, stage: int) -> np.ndarray:
        """The recorded observations of stage ``stage``'s layout, oldest first (at most H rows)."""
        length, size = self._history_shape[stage]
        value = context.get_discrete_state(self._history_index[stage]).get_value()
        rows = value[1:].reshape(length, size)
        return rows[length - int(value[0]):]

    def _append(self, context: Context, discrete_state: DiscreteValues, stage: int, executing: int,
                steps: int) -> np.ndarray:
        length, size = self._history_shape[stage]
        value = context.get_discrete_state(self._history_index[stage]).get_value()
        shifted = np.empty_like(value)  # [count, rows]: drop the oldest row, append the new observation.
        count = shifted[0] = min(int(value[0]) + 1, length)
        shifted[1:-size] = value[1 + size:]
        if self._time_steps[stage]:  # Its progress, as the env appends it (steps taken in the stage so far).
            shifted[-size:-1] = self._history_ports[stage].Eval(context)
            shifted[-1] = steps / self._time_steps[stage] if stage == executing else 1.0
        else:
            shifted[-size:] = self._history_ports[stage].Eval(context)
        discrete_state.set_value(self._history_index[stage], shifted)
        return shifted[1:].reshape(length, size)[length - count:]

    def _build_bank(self) -> None:
        """(Re)builds the numpy snapshots: one batched pass per tick for all F's of one architecture."""
        if self._bank_stages:
            self._bank = FeasibilityBank([self._feasibility[stage].model for stage in self._bank_stages])

    def _current_bank(self) -> FeasibilityBank:
        """The snapshots, rebuilt first if a model's weights changed in place since they were taken."""
        if self._bank.stale():
            self._build_bank()
        return self._bank

    def score(self, stage: int, history: np.ndarray) -> float:
        """c^stage = F^stage(history) / h^stage for a (T, obs_dim) history of stage ``stage - 1``'s layout."""
        f = self._feasibility[stage]
        if stage not in self._bank_stages:
            return feasibility_score(f, history)
        index = self._bank_stages.index(stage)
        if self._bank.snapshots[index].stale():  # Only this F's weights matter for this score.
            self._build_bank()
        return self._bank.snapshots[index](history) / float(f.threshold)

    # ----------------------------------------------------------------------------------------- decision
    def tick_stages(self, stage: int) -> list[int]:
        """The stages whose scores are computed on a tick between decisions while ``stage`` executes."""
        if self._params.evaluate_every_tick:
            return list(range(1, self.num_stages))
        if self._params.trigger == "any_later":
            return list(range(stage + 1, self.num_stages))
        if self._params.trigger == "decision":
            return []
        return [stage + 1] if stage + 1 < self.num_stages else [stage]  # The last stage: its own F.

    def decide(self, stage: int, steps: int, switches: int, scores: np.ndarray,
               success: bool, full_scores=None, held: bool = False) -> tuple[int, bool, bool]:
        """The rule of the module docstring: (next stage, whether the stage restarts its clock, whether the
        decision is a feasibility switch). ``scores`` are this tick's (at least :meth:`tick_stages`');
        ``full_scores()``, when given, returns every stage's for the walk back (default: ``scores``); ``held``:
        the target object is in hand, so stages in ``free_object_stages`` cannot be switched to."""
        last = self.num_stages - 1
        budget_done = success or steps >= self._budgets[stage]
        may_switch = switches < self._params.max_switches
        # The transition out of this stage can be judged when the next stage has an F (the last stage: its own).
        judged = self._feasibility[min(stage + 1, last)] is not None
        forward = judged and bool(np.any(scores[stage + 1:] > 1.0))  # a later stage is feasible (NaN is not)
        if may_switch and judged and (forward or budget_done):
            target = walk_back(scores if full_scores is None else full_scores())
            # The last stage selecting itself at its budget's end is not restarted: the chain is done. Restarted,
            # a time-indexed policy (tool Reorient's gait) ran again from a near-goal state and turned the tool a
            # further half turn (11 of 102 held-out hammer episodes that succeeded sequentially ended 2.2-3.1 rad
            # off). A walk back to an earlier stage (a dropped tool) still switches.
            if not (held and self._free_object[target]) and not target == stage == last:
                return target, True, True
        elif may_switch and judged and self._params.evaluate_every_tick:
            target = walk_back(scores)
            if target != stage and not (held and self._free_object[target]):
                return target, True, True
        if budget_done:
            return min(stage + 1, last), stage < last, False
        return stage, False, False

    # ------------------------------------------------------------------------------------------- events
    def _initialize(self, context: Context, discrete_state: DiscreteValues) -> None:
        for stage, index in self._history_index.items():
            discrete_state.set_value(index, np.zeros(1 + int(np.prod(self._history_shape[stage]))))
        discrete_state.set_value(self._status_index, np.zeros(3))
        discrete_state.set_value(self._scores_index, np.full(self.num_stages, np.nan))
        discrete_state.set_value(self._entries_index, np.zeros(1))

    def _compute(self, histories: dict, stages: Sequence[int], scores: np.ndarray) -> None:
        """Writes c^i of ``stages`` (those with an F) into ``scores``; bank F's in one batched pass when all of
        them are asked for, one by one otherwise."""
        stages = [stage for stage in stages if self._feasibility[stage] is not None]
        if len(self._bank_stages) > 1 and set(self._bank_stages) <= set(stages):
            values = self._current_bank()([histories[stage - 1] for stage in self._bank_stages])
            scores[self._bank_stages] = values / [float(self._feasibility[i].threshold) for i in self._bank_stages]
            stages = [stage for stage in stages if stage not in self._bank_stages]
        for stage in stages:
            scores[stage] = self.score(stage, histories[stage - 1])

    def _update(self, context: Context, discrete_state: DiscreteValues) -> None:
        status = context.get_discrete_state(self._status_index).get_value().copy()
        stage, steps, switches = int(status[_STAGE]), int(status[_STEPS]), int(status[_SWITCHES])
        histories = {source: self._append(context, discrete_state, source, stage, steps)
                     for source in self._history_index}
        fresh = np.full(self.num_stages, np.nan)  # This tick's scores; NaN where not computed (or no F).
        computed = self.tick_stages(stage)
        self._compute(histories, computed, fresh)

        def full_scores() -> np.ndarray:
            self._compute(histories, [i for i in range(1, self.num_stages) if i not in computed], fresh)
            computed[:] = range(1, self.num_stages)
            return fresh

        approaching = self._approach_port.HasValue(context) and self._approach_port.Eval(context)[0] > 0.5
        if approaching:  # The stage clock stops and nothing is decided while the OSC approaches.
            target, restart, switched = stage, False, False
        else:
            steps += 1
            success = any(port.HasValue(context) and port.Eval(context)[0] > 0.5
                          for port in (self._success_port, self._done_port))
            held = self._held_port.HasValue(context) and self._held_port.Eval(context)[0] > 0.5
            target, restart, switched = self.decide(stage, steps, switches, fresh, bool(success), full_scores, held)
        scores = context.get_discrete_state(self._scores_index).get_value().copy()
        scores[computed] = fresh[computed]  # The others keep their last computed values.
        discrete_state.set_value(self._scores_index, scores)
        discrete_state.set_value(self._status_index, np.array(
            [target, 0 if restart else steps, switches + int(switched)], dtype=float))
        # The approach brings the hand back to the hover point when a stage starts over there: on entering a stage
        # flagged approach_on_entry (in sequence or by a switch), and on a switch back to this or an earlier stage
        # (a retry or a recovery). A switch forward into an unflagged stage starts it where the hand is, as the
        # sequential advance does (forward initialization): tool Reorient, entered by a switch, had its held hammer
        # carried to a hover point over the goal first, from where it was not trained, and lost 14 of 102 held-out
        # episodes that the sequential chain turned.
        if (target != stage and self._approach_on_entry[target]) or (switched and target <= stage):
            entries = context.get_discrete_state(self._entries_index).get_value()[0]
            discrete_state.set_value(self._entries_index, np.array([entries + 1.0]))

    def done_for(self, context: Context) -> int:
        """Control ticks the chain has been done for: its last stage running past its step budget, which happens
        only when no feasibility switch restarted a stage at the budget's end (none left, or none judged; the
        sequential rule keeps the last stage running); 0 while it is not done."""
        status = context.get_discrete_state(self._status_index).get_value()
        last = self.num_stages - 1
        return max(0, int(status[_STEPS]) - int(self._budgets[last])) if int(status[_STAGE]) == last else 0

    def _calc_stage(self, context: Context, output: BasicVector) -> None:
        output.SetAtIndex(0, context.get_discrete_state(self._status_index).GetAtIndex(_STAGE))

    def _calc_switches(self, context: Context, output: BasicVector) -> None:
        output.SetAtIndex(0, context.get_discrete_state(self._status_index).GetAtIndex(_SWITCHES))

    def _calc_epoch(self, context: Context, output: BasicVector) -> None:
        output.SetAtIndex(0, context.get_discrete_state(self._entries_index).GetAtIndex(0))
