"""The task suite (sigma_data/suite.py): lookups, clear errors, spec sanity and deterministic resets."""

from __future__ import annotations

import numpy as np
import pytest

from sigma_data.suite import TASKS, get_task, get_variation, make_env, reset_env
from sigma_data.tasks.spec import TaskSpec, Variation


def test_suite_has_five_tasks_and_ten_variations():
    assert set(TASKS) == {"lift", "stack", "pick_place", "nut_assembly", "door"}
    assert sum(len(t.variations) for t in TASKS.values()) == 10
    assert get_task("pick_place").variation_names == ("milk", "bread", "cereal", "can")


def test_unknown_task_names_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown task 'stak'.*lift.*stack"):
        get_task("stak")


def test_unknown_variation_names_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown variation 'blue_on_red'.*red_on_green, green_on_red"):
        get_variation(get_task("stack"), "blue_on_red")


@pytest.mark.parametrize("name", sorted(TASKS))
def test_spec_is_sane(name: str):
    task = TASKS[name]
    assert task.name == name
    lo, hi = np.array(task.bounds[:3]), np.array(task.bounds[3:])
    assert np.all(hi > lo)
    assert lo[2] < 0.8 < hi[2], "the table top (z = 0.8) must lie inside the workspace"
    for variation in task.variations:
        assert variation.instruction == variation.instructions[0]
        assert len(set(variation.instructions)) == len(variation.instructions) >= 2
    # Instructions tell variations apart: no instruction is shared by two variations of one task.
    all_instructions = [i for v in task.variations for i in v.instructions]
    assert len(set(all_instructions)) == len(all_instructions)


def test_spec_rejects_bad_bounds_and_duplicate_variations():
    lift = get_task("lift")
    with pytest.raises(ValueError, match="bounds"):
        TaskSpec(**{**lift.__dict__, "bounds": (0, 0, 0, 1, -1, 1)})
    dup = Variation("a", ("do a",), {})
    with pytest.raises(ValueError, match="unique"):
        TaskSpec(**{**lift.__dict__, "variations": (dup, dup)})
    with pytest.raises(ValueError, match="instruction"):
        Variation("empty", (), {})


def test_make_env_rejects_unknown_camera():
    with pytest.raises(ValueError, match=r"unknown camera\(s\) \['topview'\].*agentview"):
        make_env(get_task("lift"), cameras=("agentview", "topview"), height=16, width=16)


def _state(env) -> np.ndarray:
    return np.array(env.sim.get_state().flatten())


@pytest.mark.parametrize("name", ["lift", "stack", "pick_place"])
def test_reset_is_deterministic_and_opens_the_gripper(name: str):
    task = get_task(name)
    variation = task.variations[0]
    env = make_env(task)
    try:
        reset_env(env, task, variation, seed=7)
        first = _state(env)
        reset_env(env, task, variation, seed=8)
        other = _state(env)
        reset_env(env, task, variation, seed=7)
        again = _state(env)
        q = env.sim.data.qpos[env.robots[0]._ref_gripper_joint_pos_indexes["right"]]
    finally:
        env.close()
    np.testing.assert_array_equal(first, again)
    assert not np.allclose(first[1:], other[1:]), "different seeds should place objects differently"
    assert q[0] - q[1] > 0.075, f"gripper not fully open after reset: width {q[0] - q[1]:.4f} m"


def test_reset_leaves_global_random_state_alone():
    task = get_task("lift")
    env = make_env(task)
    try:
        np.random.seed(123)
        expected = np.random.rand()
        np.random.seed(123)
        reset_env(env, task, task.variations[0], seed=0)
        assert np.random.rand() == expected
    finally:
        env.close()


def test_reset_rejects_foreign_variation():
    lift, stack = get_task("lift"), get_task("stack")
    env = make_env(lift)
    try:
        with pytest.raises(ValueError, match="does not belong"):
            reset_env(env, lift, stack.variations[0], seed=0)
    finally:
        env.close()


def test_same_seed_gives_same_state_in_a_fresh_env():
    task = get_task("stack")
    variation = get_variation(task, "green_on_red")
    states = []
    for warmup_seed in (None, 3):  # a fresh env, and one that already ran another episode
        env = make_env(task)
        try:
            if warmup_seed is not None:
                reset_env(env, task, variation, seed=warmup_seed)
                env.step(np.array([0.5, 0, 0, 0, 0, 0, 1.0]))
            reset_env(env, task, variation, seed=11)
            states.append(_state(env))
        finally:
            env.close()
    np.testing.assert_array_equal(states[0], states[1])


def test_scene_bounds_is_the_union_of_the_task_boxes():
    from sigma_data.suite import scene_bounds

    assert scene_bounds(["lift"]) == get_task("lift").bounds
    box = scene_bounds(["lift", "pick_place"])
    for name in ("lift", "pick_place"):
        lo, hi = np.array(get_task(name).bounds[:3]), np.array(get_task(name).bounds[3:])
        assert np.all(np.array(box[:3]) <= lo) and np.all(np.array(box[3:]) >= hi)
    assert box == get_task("pick_place").bounds  # Lift's box lies inside PickPlace's
    # a variation has its task's box
    assert scene_bounds(["pick_place:bread"]) == get_task("pick_place").bounds
    with pytest.raises(ValueError, match="unknown task"):
        scene_bounds(["lift", "juggle"])


def test_door_progress_reads_the_hinge_and_the_lever():
    """Evaluation records Door's joints at every keyframe (``TaskSpec.progress``): closed at reset, and what
    moving the joints moves; tasks whose objects' poses say how far they got have none."""
    task = get_task("door")
    assert get_task("lift").progress is None
    env = make_env(task)
    try:
        reset_env(env, task, task.variations[0], seed=0)
        assert task.progress(env) == {"hinge_rad": 0.0, "lever_rad": 0.0}
        env.sim.data.qpos[env.hinge_qpos_addr] = -0.001  # pushed shut: no minus sign in a failure's text
        assert str(task.progress(env)["hinge_rad"]) == "0.0"
        env.sim.data.qpos[env.hinge_qpos_addr] = 0.31
        env.sim.data.qpos[env.handle_qpos_addr] = -1.3
        assert task.progress(env) == {"hinge_rad": 0.31, "lever_rad": 1.3}
        assert task.success(env, task.variations[0])
    finally:
        env.close()
