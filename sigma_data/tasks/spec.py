"""The types a task is described by: :class:`Variation` (one instruction family) and :class:`TaskSpec`.

The registry of sigma's tasks is :mod:`sigma_data.suite`; the modules beside this one (``lift``, ``stack``, ...)
hold what each task knows about its scene (object names, success checks) and import nothing from the suite, so
experts can use them without an import cycle.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from sigma_data.experts.base import ExpertFn

Bounds = tuple[float, float, float, float, float, float]
SuccessFn = Callable[[Any, "Variation"], bool]
TargetFn = Callable[[Any, "Variation"], np.ndarray]
PointsFn = Callable[[Any, "Variation"], np.ndarray]
ProgressFn = Callable[[Any], dict[str, float]]
PlacementFn = Callable[[Any, "Variation"], dict[str, int]]


@dataclass(frozen=True)
class Variation:
    """One language-conditioned variant of a task.

    ``instructions[0]`` is the canonical instruction; the others are paraphrases for training.
    ``params`` tells the expert and the success check what the instruction asks (e.g. ``{"object": "milk"}``).
    """

    name: str
    instructions: tuple[str, ...]
    params: Mapping[str, Any]

    def __post_init__(self) -> None:
        if not self.instructions:
            raise ValueError(f"variation '{self.name}' needs at least one instruction")
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    @property
    def instruction(self) -> str:
        """The canonical instruction."""
        return self.instructions[0]


@dataclass(frozen=True)
class TaskSpec:
    """A robosuite task: environment, variations, policy workspace, expert and success check.

    ``bounds`` is the policy workspace box ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in world metres (cubes,
    so voxel grids and orthographic virtual views stay isotropic); robosuite's table top is at z = 0.8.
    ``max_steps`` is the control-step budget of one expert episode (20 steps = 1 s). ``target`` gives, for a
    scene with several objects, where the variation's object is grasped (world xyz, metres): evaluation names the
    object a policy went for with it (``pipelines/failures.py``); None for a task with one object. ``points`` gives
    the world vertices (N, 3) of the variation's object, from which evaluation measures how wide the object is
    across the open fingers and how far off their centre it is at each keyframe; None where not defined.
    ``centre`` gives, for an object grasped by a handle off its middle (the nuts), the object's centre (world xyz):
    with ``target`` (the handle) evaluation measures how far round the object from its handle a grasp came down.
    ``progress`` gives the task's joint readings that success is judged by, rounded, by name (Door's hinge and lever
    angles): evaluation records them at each keyframe, so a failure says how far the task got; None where the
    objects' poses say it. ``placement`` says how the variation's object sits over where it must end, by name and
    in whole units (NutAssembly: the nut's distance from its peg and how far inside the hole the peg stays),
    ``{}`` where it is not over it: evaluation records it at each keyframe, so a drop says how far off it was.
    """

    name: str
    env_name: str
    env_kwargs: Mapping[str, Any]
    variations: tuple[Variation, ...]
    bounds: Bounds
    expert: ExpertFn
    success: SuccessFn
    max_steps: int
    target: TargetFn | None = None
    points: PointsFn | None = None
    centre: TargetFn | None = None
    progress: ProgressFn | None = None
    placement: PlacementFn | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "env_kwargs", MappingProxyType(dict(self.env_kwargs)))
        lo, hi = np.asarray(self.bounds[:3]), np.asarray(self.bounds[3:])
        if len(self.bounds) != 6 or np.any(hi <= lo):
            raise ValueError(
                f"task '{self.name}': bounds must be (xmin, ymin, zmin, xmax, ymax, zmax), got {self.bounds}"
            )
        names = [v.name for v in self.variations]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"task '{self.name}': variation names must be unique and non-empty, got {names}")

    @property
    def variation_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.variations)
