"""The observation spec recorded in chaining files (feasibility models, terminal buffers).

A model trained on one observation layout silently produces garbage on another of the same size, so every file
records the layout's size and a human-readable description (e.g. the observation table's term names and sizes);
loading checks both and names the two specs in the error.
"""

import dataclasses
import hashlib


@dataclasses.dataclass(frozen=True)
class ObservationSpec:
    """What one observation vector is."""

    dim: int
    """Length of the observation vector."""
    description: str
    """Human-readable layout, e.g. ``"grasp: hand_q(16) hand_dq(16) object_pose(7) ..."``; compared verbatim."""

    def __post_init__(self):
        if int(self.dim) <= 0:
            raise ValueError(f"observation dim must be positive, got {self.dim}")
        object.__setattr__(self, "dim", int(self.dim))
        object.__setattr__(self, "description", str(self.description))

    @property
    def digest(self) -> str:
        """A short hash of dim and description (16 hex digits), handy in logs and file names."""
        return hashlib.sha256(f"{self.dim}|{self.description}".encode()).hexdigest()[:16]

    def __str__(self) -> str:
        return f"ObservationSpec(dim={self.dim}, digest={self.digest}, description={self.description!r})"

    def to_dict(self) -> dict:
        return {"dim": self.dim, "description": self.description, "digest": self.digest}

    @classmethod
    def from_dict(cls, data: dict) -> "ObservationSpec":
        return cls(dim=int(data["dim"]), description=str(data["description"]))

    def check(self, expected: "ObservationSpec | None", what: str) -> None:
        """Raises ValueError naming ``what`` (e.g. the file) and both specs unless ``expected`` is None or equal."""
        if expected is not None and expected != self:
            raise ValueError(f"{what} was made for observations {self}, but the caller expects {expected}; "
                             f"re-create it with the current observation layout")
