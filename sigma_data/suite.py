"""Registry of the robosuite tasks sigma collects: language variations, success checks, experts, bounds.

Quick start (what the collection pipeline does per episode)::

    from sigma_data.suite import get_task, get_variation, make_env, reset_env

    task = get_task("stack")
    variation = get_variation(task, "green_on_red")
    env = make_env(task, cameras=("agentview", "robot0_eye_in_hand"), height=128, width=128)
    reset_env(env, task, variation, seed=3)           # deterministic; gripper fully open
    task.expert(recorder, variation, np.random.default_rng(3))  # recorder.env is env; may raise ExpertFailure
    ok = task.success(env, variation)                  # the instruction decides what success means

Each :class:`TaskSpec` is one robosuite environment with several :class:`Variation` s; for most tasks the
instruction names *which* object/goal counts, so a multi-task policy must read it. Adding a task is one
entry in :data:`TASKS` plus one expert module under :mod:`sigma_data.experts`.

Environment: Panda, robosuite's default composite BASIC controller (arm OSC_POSE delta, 5 cm / 0.5 rad
per unit action), 20 Hz control, no camera observations (render from ``env.sim`` yourself), ``hard_reset=False``
(render-context settings survive resets), ``ignore_done=True``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sigma_data.experts.door import door_expert
from sigma_data.experts.lift import lift_expert
from sigma_data.experts.nut_assembly import nut_assembly_expert
from sigma_data.experts.pick_place import pick_place_expert
from sigma_data.experts.stack import stack_expert
from sigma_data.tasks import door, lift, nut_assembly, pick_place, stack
from sigma_data.tasks.spec import Bounds, TaskSpec, Variation

ROBOT = "Panda"
CONTROL_FREQ = 20
CONTROLLER = "BASIC"  # composite controller; its arm part is OSC_POSE (delta, base frame)


def _v(name: str, params: Mapping[str, Any], *instructions: str) -> Variation:
    return Variation(name=name, instructions=tuple(instructions), params=params)


# Lift and Stack: cubes within 8 cm of the table centre, keyframes up to 17 cm above the table, the gripper's start
# pose 13 cm behind the centre. A 36 cm box holds the whole grip-site path with >= 4 cm to spare and gives the
# `small` preset's 64² views 5.6 mm voxels (a 60 cm box: 9.4 mm, a 4 cm cube 4 pixels wide).
TABLETOP_BOX: Bounds = (-0.18, -0.18, 0.75, 0.18, 0.18, 1.11)

TASKS: dict[str, TaskSpec] = {
    spec.name: spec
    for spec in (
        TaskSpec(
            name="lift",
            env_name="Lift",
            env_kwargs={},
            variations=(
                _v("lift_cube", {}, "lift the cube", "pick up the cube", "raise the red cube off the table"),
            ),
            bounds=TABLETOP_BOX,
            expert=lift_expert,
            success=lift.success,
            max_steps=200,
        ),
        TaskSpec(
            name="stack",
            env_name="Stack",
            env_kwargs={},
            variations=(
                _v(
                    "red_on_green",
                    {"top": "cubeA", "bottom": "cubeB"},
                    "stack the red cube on the green cube",
                    "put the red block on top of the green block",
                    "place the red cube onto the green one",
                ),
                _v(
                    "green_on_red",
                    {"top": "cubeB", "bottom": "cubeA"},
                    "stack the green cube on the red cube",
                    "put the green block on top of the red block",
                    "place the green cube onto the red one",
                ),
            ),
            bounds=TABLETOP_BOX,
            expert=stack_expert,
            success=stack.success,
            target=stack.target,
            max_steps=400,
        ),
        TaskSpec(
            name="pick_place",
            env_name="PickPlace",
            env_kwargs={"single_object_mode": 0},
            variations=tuple(
                _v(
                    obj,
                    {"object": obj},
                    f"put the {obj} in its bin",
                    f"place the {obj} into its bin",
                    f"move the {obj} to its bin",
                    f"pick up the {obj} and drop it in its bin",
                )
                for obj in pick_place.OBJECTS
            ),
            bounds=(-0.4, -0.5, 0.75, 0.6, 0.5, 1.75),
            expert=pick_place_expert,
            success=pick_place.success,
            target=pick_place.target,
            points=pick_place.points,
            max_steps=500,
        ),
        TaskSpec(
            name="nut_assembly",
            env_name="NutAssembly",
            env_kwargs={"single_object_mode": 0},
            variations=(
                _v(
                    "square_nut",
                    {"nut": "square"},
                    "put the square nut on the square peg",
                    "fit the square nut onto the square peg",
                    "place the square nut around the square peg",
                ),
                _v(
                    "round_nut",
                    {"nut": "round"},
                    "put the round nut on the round peg",
                    "fit the round nut onto the round peg",
                    "place the round nut around the round peg",
                ),
            ),
            bounds=(-0.3, -0.35, 0.78, 0.4, 0.35, 1.48),
            expert=nut_assembly_expert,
            success=nut_assembly.success,
            target=nut_assembly.target,
            centre=nut_assembly.centre,
            placement=nut_assembly.placement,
            max_steps=600,
        ),
        TaskSpec(
            name="door",
            env_name="Door",
            env_kwargs={"use_latch": True},
            variations=(
                _v(
                    "open_door",
                    {},
                    "open the door",
                    "pull the door open",
                    "turn the handle and open the door",
                ),
            ),
            bounds=door.BOUNDS,
            expert=door_expert,
            success=door.success,
            progress=door.progress,
            max_steps=600,
        ),
    )
}


def get_task(name: str) -> TaskSpec:
    """The registered task called ``name``; ``ValueError`` listing the known tasks otherwise."""
    try:
        return TASKS[name]
    except KeyError:
        raise ValueError(f"unknown task '{name}'; known tasks: {', '.join(sorted(TASKS))}") from None


def expand_tasks(specs: Sequence[str]) -> list[tuple[str, str]]:
    """``["lift", "stack:green_on_red"]`` or ``["all"]`` -> [(task, variation), ...] in order, each pair once: a task
    named alone stands for all its variations. Unknown names raise ``ValueError`` naming them."""
    if list(specs) == ["all"]:
        specs = list(TASKS)
    out: list[tuple[str, str]] = []
    for spec in specs:
        name, _, variation = spec.partition(":")
        task = get_task(name)
        names = [get_variation(task, variation).name] if variation else list(task.variation_names)
        out += [(task.name, v) for v in names if (task.name, v) not in out]
    return out


def scene_bounds(task_names: Sequence[str]) -> tuple[float, ...]:
    """The smallest box holding the workspace bounds of every named task (``"pick_place"``, or one of its
    variations, ``"pick_place:bread"``, which has its task's box): the policy's ``scene_bounds``.

    Train a multi-task policy on this box (``--policy.scene_bounds``); a box much larger than the workspace
    wastes virtual-view pixels (the ``small`` policy's 64² views then resolve ~1.6 cm instead of ~0.9 cm).
    """
    if not task_names:
        raise ValueError("scene_bounds needs at least one task name")
    tasks = dict.fromkeys(task for task, _ in expand_tasks(task_names))
    boxes = np.array([get_task(name).bounds for name in tasks], dtype=float)
    return (*map(float, boxes[:, :3].min(0)), *map(float, boxes[:, 3:].max(0)))


def get_variation(task: TaskSpec, name: str) -> Variation:
    """The variation of ``task`` called ``name``; ``ValueError`` listing its variations otherwise."""
    for variation in task.variations:
        if variation.name == name:
            return variation
    raise ValueError(
        f"unknown variation '{name}' for task '{task.name}'; known variations: {', '.join(task.variation_names)}"
    )


def make_env(
    task: TaskSpec,
    cameras: Sequence[str] = (),
    height: int = 128,
    width: int = 128,
    model_seed: int | None = 0,
) -> Any:
    """Create the robosuite environment of ``task``.

    Panda with the default composite BASIC controller (arm OSC_POSE delta), ``control_freq=20``, no camera
    observations (``use_camera_obs=False``), an offscreen renderer only if ``cameras`` are given (configured
    for those cameras at ``height`` x ``width`` so ``env.sim.render`` works), ``ignore_done=True`` and
    ``hard_reset=False``. Raises ``ValueError`` naming an unknown camera.

    Some scenes draw model parameters when they are built (Lift's cube size) from NumPy's global generator; they
    are drawn under ``model_seed`` (the caller's random state is restored), so collection, replay and evaluation
    envs of a task share one model. ``None`` leaves them random.
    """
    import robosuite as suite
    from robosuite.controllers import load_composite_controller_config

    from sigma_data.mujoco_gl import quiet_robosuite

    quiet_robosuite()

    cameras = list(cameras)
    if height <= 0 or width <= 0:
        raise ValueError(f"image size must be positive, got height={height}, width={width}")
    kwargs: dict[str, Any] = {
        "robots": ROBOT,
        "controller_configs": load_composite_controller_config(controller=CONTROLLER, robot=ROBOT),
        "control_freq": CONTROL_FREQ,
        "has_renderer": False,
        "has_offscreen_renderer": bool(cameras),
        "use_camera_obs": False,
        "ignore_done": True,
        "hard_reset": False,
        **dict(task.env_kwargs),
    }
    if cameras:
        kwargs.update(camera_names=cameras, camera_heights=height, camera_widths=width, camera_depths=True)
    saved = np.random.get_state()
    try:
        if model_seed is not None:
            np.random.seed(model_seed)
        env = suite.make(task.env_name, **kwargs)
    finally:
        np.random.set_state(saved)
    known = set(env.sim.model.camera_names)
    unknown = [c for c in cameras if c not in known]
    if unknown:
        close_env(env)
        raise ValueError(
            f"unknown camera(s) {unknown} for task '{task.name}' ({task.env_name}); known: {', '.join(sorted(known))}"
        )
    return env


def close_env(env: Any) -> None:
    """Close a robosuite env made by :func:`make_env`; close every env this way, never with ``env.close()`` alone.

    robosuite frees an env's offscreen render context (its MuJoCo textures and framebuffers) in whichever OpenGL
    context is current when the context is collected. GL object names are numbered per context, so when another
    env's context is current, or a reference (a :class:`~sigma_data.cameras.CameraRig`) keeps the context alive
    until a later env renders, that frees the *other* env's objects under the same names, and it renders garbage
    (measured: an env made after another was closed rendered noise and font glyphs). Here the context is freed
    first, inside its own GL context; robosuite's later free finds nothing left.
    """
    sim = getattr(env, "sim", None)
    ctx = getattr(sim, "_render_context_offscreen", None)
    if ctx is not None and getattr(ctx, "gl_ctx", None) is not None:
        ctx.gl_ctx.make_current()
        ctx.con.free()
        ctx.gl_ctx.free()
    env.close()


def reset_env(env: Any, task: TaskSpec, variation: Variation, seed: int) -> None:
    """Reset ``env`` to the initial state of episode ``seed`` and open the gripper fully.

    robosuite samples object placements and robot initial noise from NumPy's global generator; it is seeded
    with ``seed`` for the reset and restored afterwards, so the same seed gives the same initial sim state and
    the caller's global random state is untouched. robosuite resets the Panda gripper half-open; an
    unrecorded pre-roll then opens it fully while holding the arm pose, so recording starts settled.
    """
    from sigma_data.control import EnvDriver, actuate_gripper

    if variation not in task.variations:
        raise ValueError(f"variation '{variation.name}' does not belong to task '{task.name}'")
    saved = np.random.get_state()
    try:
        np.random.seed(seed)
        env.reset()
    finally:
        np.random.set_state(saved)
    actuate_gripper(EnvDriver(env), open=True)
    env.sim.forward()
