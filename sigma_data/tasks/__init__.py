"""What sigma knows about each robosuite task's scene: object names, goal sites, success checks.

One module per task (``lift``, ``stack``, ``pick_place``, ``nut_assembly``, ``door``) and the types tasks are
described by (:mod:`sigma_data.tasks.spec`); shape measures of an object's vertices that the experts and the
evaluation share (:mod:`sigma_data.tasks.geometry`). The registry that ties each task to its variations, expert and
workspace box is :mod:`sigma_data.suite`; nothing here imports it.
"""

from sigma_data.tasks.spec import Bounds, SuccessFn, TaskSpec, Variation

__all__ = ["Bounds", "SuccessFn", "TaskSpec", "Variation"]
