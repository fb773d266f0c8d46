"""The objects of each task family, by key: Building Blocks' block types (1-5 trained, 6-8 unseen) and Tool
Positioning's tools (the hammer trained; spatula and spoon unseen), with their labels and training split, and the
lookup from the names a user types (``--objects``) to those keys."""

from seqdex_drake.modeling.blocks import BLOCK_SPECS
from seqdex_drake.modeling.tools import TOOL_SPECS


def objects_of(family: str) -> list[tuple]:
    """(key, label, trained) per object of the family."""
    if family == "building_blocks":
        return [(t, f"Block {t}", BLOCK_SPECS[t].split == "trained") for t in sorted(BLOCK_SPECS)]
    return [(k, name, k == 0) for k, name in enumerate(TOOL_SPECS)]


def object_keys(family: str, names) -> tuple:
    """The object keys of ``names``: tool names (hammer, spatula, spoon) or block types ("1" .. "8"), in
    :func:`objects_of` order, duplicates dropped. Raises ValueError naming the valid ones."""
    objects = objects_of(family)
    valid = {label if family == "tool_positioning" else str(key): key for key, label, _ in objects}
    unknown = [name for name in names if str(name) not in valid]
    if unknown:
        kind = "tool" if family == "tool_positioning" else "block type"
        raise ValueError(f"unknown {kind}{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}; "
                         f"valid {family} objects: {', '.join(valid)}")
    keep = {valid[str(name)] for name in names}
    return tuple(key for key, _, _ in objects if key in keep)
