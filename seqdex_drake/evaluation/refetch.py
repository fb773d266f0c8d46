"""Fetching another block of the same type when the retrieve could not take the target out of the pile.

The assembly manual asks for a block of a *type*, and the pile holds nine of each. The chain fetches the one easiest
to take out (``ChainRunner.pick_block``), but some cannot be taken out: the retrieve gives up on blocks wedged among
their neighbours on the box floor (``tasks/scripted/block_retrieve_script.py``). Restarting the chain on the same
block (the switcher's restart from Search) meets the same neighbours again. So, as a person would reach for the
next identical block, the runner fetches the next-easiest block of the type once the retrieve stage has ended
with its target still in the box (``ChainRunner.target_in_pile``): it gave up, or ran out of its budget before the
block was out. A block that is out of the box is kept, wherever it lies on the table: Orient and Grasp act there,
and the switcher's restarts (Search, then the retrieve again) may move a block that was already set down; fetching
another then threw away a block stood up or about to be (2 of 32 held-out seeds placed before, not after, in the
first measurement of this rule, which also refetched blocks lying outside the staging area). The chain restarts on
the new block (``ChainRunner.start_block``); the episode's clock runs on, so the refetches share the object's time
limit.

:class:`RetrieveWatch` is the test, read once per control tick by ``ChainRunner.run``.
"""

from __future__ import annotations


class RetrieveWatch:
    """Says when the retrieve stage has just ended with its target still in the pile; counts the refetches.

    Args:
        tasks: the chain's stages; without a ``retrieve`` stage the watch never fires.
        limit: the most refetches per object (``RunConfig.refetches``).
    """

    def __init__(self, tasks: list[str], limit: int):
        if limit < 0:
            raise ValueError(f"refetches must be >= 0, got {limit}")
        self.stage = tasks.index("retrieve") if "retrieve" in tasks else None
        self.limit = int(limit)
        self.used = 0
        self._previous = -1

    def start_object(self) -> None:
        """A new object's episode: no refetch used yet."""
        self.used = 0
        self._previous = -1

    def restart(self) -> None:
        """The chain restarted at stage 0 (a refetch or a restart on the same target)."""
        self._previous = -1

    def due(self, active_stage: int, in_pile) -> bool:
        """Whether to fetch another block now: the chain left the retrieve stage at this tick, ``in_pile()`` (the
        target still in the box) is True, and a refetch is left."""
        left = self._previous == self.stage and active_stage != self.stage
        self._previous = int(active_stage)
        return self.stage is not None and left and self.used < self.limit and bool(in_pile())
