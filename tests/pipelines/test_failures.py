"""sigma-eval's per-episode failure reasons (pipelines/failures.py), from keyframe traces and real robosuite scenes
(the rollouts themselves run in test_demo)."""

from __future__ import annotations

import pytest

from pipelines.evaluate import markdown_table, summarise
from pipelines.failures import failure_kind, failure_reason
from pipelines.rollout import EpisodeResult


def _step(
    k, xyz, grip=1.0, status="converged", closed=False, opened=False, gap=0.08, quat=(1.0, 0.0, 0.0, 0.0)
):
    return {
        "keyframe": k,
        "action": [*xyz, *quat, grip, 0.0],
        "arm_status": status,
        "closed_now": closed,
        "opened_now": opened,
        "finger_gap_m": gap,
    }


def _result(trace, success=False, error=None):
    return EpisodeResult("lift", "lift_cube", 7, success, len(trace), 100, 1.0, None, error, trace=trace)


PREGRASP, GRASP, LIFT = (0.0, 0.0, 0.9), (0.0, 0.0, 0.82), (0.0, 0.0, 0.97)


@pytest.mark.parametrize(
    ("trace", "reason"),
    [
        # closed on nothing: the fingers met
        (
            [_step(1, PREGRASP), _step(2, GRASP), _step(3, GRASP, 0.0, closed=True, gap=0.002)],
            "grasp missed at keyframe 3",
        ),
        # the approach stalled on the object and the close ended before the fingers met: they meet by the next
        # keyframe, so the grasp held nothing (it used to read as "dropped" when the gripper later opened)
        (
            [
                _step(1, PREGRASP),
                _step(2, GRASP, status="stalled"),
                _step(3, GRASP, 0.0, status="stalled", closed=True, gap=0.064),
                _step(4, LIFT, 0.0, gap=0.001),
                _step(5, LIFT, 1.0, opened=True),
            ],
            "grasp missed at keyframe 3",
        ),
        # held the cube, then let go away from success
        (
            [_step(1, GRASP, 0.0, closed=True, gap=0.04), _step(2, LIFT, 1.0, opened=True)],
            "dropped at keyframe 2",
        ),
        # asked for the same place twice with the same gripper command
        (
            [_step(1, GRASP, 0.0, closed=True, gap=0.04), _step(2, GRASP, 0.0), _step(3, GRASP, 0.0)],
            "repeats keyframe 1",
        ),
        # turned in place (Door's first keyframes turn the hand before the approach): progress, not a repeat
        (
            [_step(1, PREGRASP), _step(2, PREGRASP, quat=(0.7071, 0.0, 0.0, 0.7071)), _step(3, GRASP)],
            "timeout after 3 keyframes (stopped)",
        ),
        # one 5° bin of turn at the same place is a jitter, not progress: a repeat (0.9990, 0.0436 is 5.0° about x)
        (
            [
                _step(1, GRASP, 0.0, closed=True, gap=0.04),
                _step(2, LIFT, 0.0),
                _step(3, LIFT, 0.0, quat=(0.999, 0.0436, 0.0, 0.0)),
            ],
            "repeats keyframe 2",
        ),
        # the same orientation written with the other sign is the same orientation: a repeat
        (
            [
                _step(1, GRASP, 0.0, closed=True, gap=0.04),
                _step(2, LIFT, 0.0),
                _step(3, LIFT, 0.0, quat=(-1, 0, 0, 0)),
            ],
            "repeats keyframe 2",
        ),
        (
            [_step(1, PREGRASP), _step(2, (0.5, 0.5, 0.5), status="stalled")],
            "keyframe 2 not reached (stalled)",
        ),
        ([_step(k, (0.0, 0.0, 0.8 + 0.05 * k)) for k in range(1, 13)], "timeout after 12 keyframes"),
    ],
)
def test_failure_reasons(trace, reason):
    assert failure_reason(_result(trace), max_keyframes=12) == reason


def test_a_task_with_progress_says_where_its_joints_ended():
    """Door: the last keyframe's hinge and lever angles follow a stall or a timeout."""
    door = {"hinge_rad": 0.05, "lever_rad": 0.8}
    trace = [_step(1, PREGRASP), _step(2, GRASP, status="stalled") | {"progress": door}]
    assert (
        failure_reason(_result(trace), 12)
        == "keyframe 2 not reached (stalled); at the end hinge_rad 0.05, lever_rad 0.8"
    )
    trace = [_step(k, (0.0, 0.0, 0.8 + 0.05 * k)) | {"progress": door} for k in range(1, 13)]
    assert (
        failure_reason(_result(trace), 12)
        == "timeout after 12 keyframes; at the end hinge_rad 0.05, lever_rad 0.8"
    )
    assert failure_kind(failure_reason(_result(trace), 12)) == "timeout"


def test_a_missed_grasp_says_how_the_object_sat_between_the_fingers():
    """From the grasp pose before the close (fingers open), else from the close itself."""
    fit = {"across_fingers_mm": 92, "off_centre_mm": 4, "below_top_mm": 36}
    trace = [_step(1, PREGRASP), _step(2, GRASP) | fit, _step(3, GRASP, 0.0, closed=True, gap=0.002)]
    reason = failure_reason(_result(trace), 12)
    assert (
        reason
        == "grasp missed at keyframe 3 (92 mm across the fingers, 4 mm off centre, 36 mm below its top)"
    )
    assert failure_kind(reason) == "grasp missed"
    trace = [_step(1, PREGRASP), _step(2, GRASP, 0.0, closed=True, gap=0.002) | fit | {"off_centre_mm": 30}]
    assert failure_reason(_result(trace), 12).endswith(
        "(92 mm across the fingers, 30 mm off centre, 36 mm below its top)"
    )
    trace[-1] |= {"ridge_deg": 80}
    assert failure_reason(_result(trace), 12).endswith(
        "(92 mm across the fingers, 30 mm off centre, 36 mm below its top, closing 80° off its ridge)"
    )


def test_a_missed_grasp_of_a_handled_object_says_how_far_round_from_its_handle():
    """A nut's missed grasp names the angle round the nut from its handle, from the grasp pose before the close."""
    trace = [
        _step(1, PREGRASP),
        _step(2, GRASP) | {"round_from_handle_deg": -71, "from_centre_mm": 55},
        _step(3, GRASP, 0.0, closed=True, gap=0.002),
    ]
    reason = failure_reason(_result(trace), 12)
    assert (
        reason == "grasp missed at keyframe 3 (-71° round the object from its handle, 55 mm from its centre)"
    )
    assert failure_kind(reason) == "grasp missed"


def test_holding_a_nut_by_its_ring_is_named_before_what_followed():
    """A held grasp more than 25° round from the handle is the first thing that went wrong; what followed is kept.
    Within 25° the closing fingers centre the handle: a later drop is a drop."""
    from pipelines.failures import OFF_HANDLE_DEG

    placed = {"placement": {"from_peg_mm": 89, "peg_margin_mm": -78}}

    def trace(angle):
        return [
            _step(1, PREGRASP),
            _step(2, GRASP) | {"round_from_handle_deg": angle, "from_centre_mm": 46},
            _step(3, GRASP, 0.0, closed=True, gap=0.03),
            _step(4, LIFT, 0.0) | placed,
            _step(5, LIFT, 1.0, opened=True),
        ]

    reason = failure_reason(_result(trace(-88)), 12)
    assert reason == (
        "grasped off the handle at keyframe 3 (-88° round the object from its handle, 46 mm from its centre);"
        " then dropped at keyframe 5 (from peg 89 mm, peg margin -78 mm)"
    )
    assert failure_kind(reason) == "off the handle"
    assert (
        failure_reason(_result(trace(OFF_HANDLE_DEG)), 12)
        == "dropped at keyframe 5 (from peg 89 mm, peg margin -78 mm)"
    )
    # held by the ring and never let go: what followed is the timeout
    never_opened = trace(120)[:4]
    assert failure_reason(_result(never_opened), 4).startswith(
        "grasped off the handle at keyframe 3 (120° round"
    )
    assert failure_reason(_result(never_opened), 4).endswith("; then timeout after 4 keyframes")
    # a close on nothing stays a missed grasp whichever way round it came down
    missed = [*trace(120)[:2], _step(3, GRASP, 0.0, closed=True, gap=0.002)]
    assert failure_kind(failure_reason(_result(missed), 12)) == "grasp missed"


def test_a_drop_says_how_the_object_sat_over_its_goal():
    """A nut let go above its peg says, from the keyframe it was let go from, how far off the peg it was; a drop
    away from any goal says nothing more."""
    placed = {"placement": {"from_peg_mm": 9, "turned_deg": 12, "peg_margin_mm": -2}}
    trace = [
        _step(1, GRASP, 0.0, closed=True, gap=0.03),
        _step(2, LIFT, 0.0) | placed,
        _step(3, LIFT, 1.0, opened=True),
    ]
    reason = failure_reason(_result(trace), 12)
    assert reason == "dropped at keyframe 3 (from peg 9 mm, turned 12°, peg margin -2 mm)"
    assert failure_kind(reason) == "dropped"
    trace[1].pop("placement")
    assert failure_reason(_result(trace), 12) == "dropped at keyframe 3"


def test_doing_the_other_instruction_is_named_before_the_trace():
    result = _result([_step(1, GRASP, 0.0, closed=True, gap=0.04), _step(2, LIFT, 1.0, opened=True)])
    result.other_variation = "green_on_red"
    assert failure_reason(result, 12) == "wrong object: did green_on_red"
    assert failure_kind(failure_reason(result, 12)) == "wrong object"


def test_closing_at_another_variations_object_is_a_wrong_object_failure():
    # The first close decides: over the can while asked for the milk (PickPlace), however the grasp went.
    def trace(nearest):
        return [
            _step(1, PREGRASP) | {"nearest": nearest},
            _step(2, GRASP, 0.0, closed=True, gap=0.03) | {"nearest": nearest},
            _step(3, LIFT, 1.0, opened=True) | {"nearest": "milk"},
        ]

    milk = EpisodeResult("pick_place", "milk", 7, False, 3, 100, 1.0, trace=trace("can"))
    assert failure_reason(milk, 12) == "wrong object at keyframe 2: went for can"
    assert failure_kind(failure_reason(milk, 12)) == "wrong object"
    milk.trace = trace("milk")  # over the milk: the trace decides as before
    assert failure_reason(milk, 12) == "dropped at keyframe 3"


def test_success_and_errors():
    assert failure_reason(_result([_step(1, LIFT)], success=True), 12) is None
    assert (
        failure_reason(_result([], error="RuntimeError('boom')\nmore"), 12) == "error: RuntimeError('boom')"
    )
    assert failure_kind("grasp missed at keyframe 3") == "grasp missed"
    assert failure_kind("keyframe 2 not reached (budget)") == "not reached"


def test_summary_counts_failure_kinds(tmp_path):
    from pipelines.evaluate import EvalConfig

    results = [
        _result([_step(1, PREGRASP), _step(2, GRASP, 0.0, closed=True, gap=0.001)]),
        _result([_step(1, PREGRASP), _step(2, GRASP, 0.0, closed=True, gap=0.001)]),
        _result([_step(1, LIFT)], success=True),
    ]
    for r in results:
        r.failure = failure_reason(r, 12)
    summary = summarise(results, EvalConfig(output_dir=tmp_path))
    row = summary["variations"][0]
    assert row["successes"] == 1 and row["failures"] == {"grasp missed": 2}
    assert "grasp missed 2" in markdown_table(summary)


def test_the_other_stacking_order_is_recognised_in_real_robosuite():
    """The green-on-red episode whose robot stacked red on green (the red-on-green expert, same seed and scene):
    its success check fails and sigma-eval names the variation it did instead."""
    import numpy as np

    from pipelines.failures import other_variation_done
    from sigma_data.control import EnvDriver
    from sigma_data.sim_env import SigmaRobosuiteEnv
    from sigma_data.suite import get_task, get_variation

    env = SigmaRobosuiteEnv("stack:green_on_red", cameras=("agentview",), image_size=32)
    try:
        env.reset(seed=0)
        assert other_variation_done(env) is None  # nothing stacked yet
        task = get_task("stack")
        task.expert(EnvDriver(env.env), get_variation(task, "red_on_green"), np.random.default_rng(0))
        assert not task.success(env.env, env.variation)
        assert other_variation_done(env) == "red_on_green"
    finally:
        env.close()


@pytest.mark.parametrize(
    ("scene", "done_by"), [("pick_place:milk", "bread"), ("nut_assembly:square_nut", "round_nut")]
)
def test_the_object_the_hand_went_for_is_named_in_real_robosuite(scene, done_by):
    """Another variation's expert run in this scene leaves the hand at that variation's object, and the trace's
    ``nearest`` says so (``TaskSpec.target`` of PickPlace objects and NutAssembly handles)."""
    import numpy as np

    from pipelines.failures import nearest_variation
    from sigma_data.control import EnvDriver
    from sigma_data.sim_env import SigmaRobosuiteEnv
    from sigma_data.suite import get_task, get_variation

    env = SigmaRobosuiteEnv(scene, cameras=("agentview",), image_size=32)
    try:
        env.reset(seed=0)
        task = env.task
        other = get_variation(task, done_by)
        task.expert(EnvDriver(env.env), other, np.random.default_rng(0))
        assert task.success(env.env, other) and not task.success(env.env, env.variation)
        assert nearest_variation(env) == {"nearest": done_by}
    finally:
        env.close()
    assert get_task("lift").target is None
    lift = SigmaRobosuiteEnv("lift", cameras=("agentview",), image_size=32)
    try:
        assert nearest_variation(lift) == {}  # one object: nothing to tell apart
    finally:
        lift.close()


def test_how_the_object_sits_between_the_fingers_in_real_robosuite():
    """The hand driven to the expert's planned grasp of the bread (fingers open): the bread is as wide across the
    fingers as planned and centred between them; 10 cm above it the pads are not at the object, so nothing."""
    import numpy as np

    from pipelines.failures import grasp_fit
    from sigma_data.experts.pick_place import grasp_band, plan_grasp
    from sigma_data.poses import grip_site_frame, site_yaw, top_down_quat
    from sigma_data.sim_env import SigmaRobosuiteEnv

    env = SigmaRobosuiteEnv("pick_place:bread", cameras=("agentview",), image_size=32)
    try:
        env.reset(seed=0)
        pts = env.task.points(env.env, env.variation)
        band, grasp = grasp_band(pts)
        yaw, width, grasp = plan_grasp(band, site_yaw(grip_site_frame(env.env)[1]), grasp)
        quat = top_down_quat(yaw)
        env.step(np.array([*grasp[:2], grasp[2] + 0.1, *quat, 1.0, 0.0]))
        assert grasp_fit(env, "bread") == {}
        env.step(np.array([*grasp, *quat, 1.0, 1.0]))
        fit = grasp_fit(env, "bread")
        assert abs(fit["across_fingers_mm"] - 1000 * width) < 10
        assert fit["off_centre_mm"] < 10
        assert abs(fit["below_top_mm"] - 1000 * (pts[:, 2].max() - grasp[2])) < 10
        assert "ridge_deg" not in fit  # the bread's top has no ridge
    finally:
        env.close()


def test_the_milk_cartons_ridge_against_the_closing_axis_in_real_robosuite():
    """At the expert's planned milk grasp the fingers close along the gable's ridge (within 12°); turned a quarter
    turn they close across it."""
    import numpy as np

    from pipelines.failures import grasp_fit
    from sigma_data.experts.pick_place import grasp_band, plan_grasp
    from sigma_data.poses import grip_site_frame, site_yaw, top_down_quat
    from sigma_data.sim_env import SigmaRobosuiteEnv

    env = SigmaRobosuiteEnv("pick_place:milk", cameras=("agentview",), image_size=32)
    try:
        env.reset(seed=0)
        band, grasp = grasp_band(env.task.points(env.env, env.variation))
        yaw, _, grasp = plan_grasp(band, site_yaw(grip_site_frame(env.env)[1]), grasp)
        for turn, (low, high) in ((0.0, (0, 14)), (np.pi / 2, (76, 90))):
            env.step(np.array([*grasp[:2], grasp[2] + 0.1, *top_down_quat(yaw + turn), 1.0, 0.0]))
            env.step(np.array([*grasp, *top_down_quat(yaw + turn), 1.0, 1.0]))
            assert low <= grasp_fit(env, "milk")["ridge_deg"] <= high, turn
    finally:
        env.close()


def test_how_far_round_the_nut_from_its_handle_in_real_robosuite():
    """Above the expert's grasp of the square nut the hand is 0° round from the handle, 62 mm from the nut's
    centre; above the same point turned a quarter turn about the centre, 90°; 20 cm beside the nut, not at it
    (nothing). Lift has no handled object."""
    import numpy as np

    from pipelines.failures import handle_fit
    from sigma_data.experts.nut_assembly import GRASP_OFFSET, HANDLE_OUTWARD
    from sigma_data.poses import top_down_quat
    from sigma_data.sim_env import SigmaRobosuiteEnv
    from sigma_data.suite import get_task

    env = SigmaRobosuiteEnv("nut_assembly:square_nut", cameras=("agentview",), image_size=32)
    try:
        env.reset(seed=0)
        centre = env.task.centre(env.env, env.variation)
        out = (env.task.target(env.env, env.variation) - centre) * [1, 1, 0]
        grasp = centre + out * (1 + HANDLE_OUTWARD / np.linalg.norm(out)) + [0, 0, GRASP_OFFSET + 0.06]
        offset = grasp - centre
        turned = centre + np.array([-offset[1], offset[0], offset[2]])  # a quarter turn counter-clockwise
        quat = top_down_quat(float(np.arctan2(out[1], out[0])))
        for point, angle in ((grasp, 0), (turned, 90)):
            env.step(np.array([*point, *quat, 1.0, 0.0]))
            fit = handle_fit(env, "square_nut")
            assert abs(fit["round_from_handle_deg"] - angle) <= 8, (angle, fit)
            assert abs(fit["from_centre_mm"] - 62) <= 8, (angle, fit)
        env.step(np.array([centre[0], centre[1] - 0.2, grasp[2], *quat, 1.0, 0.0]))
        assert handle_fit(env, "square_nut") == {}
    finally:
        env.close()
    assert get_task("lift").centre is None


def test_how_the_nut_sits_over_its_peg_in_real_robosuite():
    """The square nut moved (as a free body) to centred over its peg and squared with it: the peg is 6.75 mm inside
    the hole all round; 5 mm off along x: 1.75 mm; turned 20° as well: the peg lands on the nut (negative); 20 cm
    away: no reading. The trace of an evaluation carries it under "placement"."""
    import numpy as np

    from pipelines.failures import placement_fit
    from sigma_data.sim_env import SigmaRobosuiteEnv
    from sigma_data.tasks.nut_assembly import nut_object, peg_body_id

    env = SigmaRobosuiteEnv("nut_assembly:square_nut", cameras=("agentview",), image_size=32)
    try:
        env.reset(seed=0)
        sim = env.env.sim
        joint = nut_object(env.env, "square").joints[0]
        peg = np.array(sim.data.body_xpos[peg_body_id(env.env, "square")])

        def place(dx, yaw_deg):
            quat = [np.cos(np.radians(yaw_deg) / 2), 0, 0, np.sin(np.radians(yaw_deg) / 2)]  # wxyz
            sim.data.set_joint_qpos(joint, [peg[0] + dx, peg[1], 1.1, *quat])
            sim.forward()
            return placement_fit(env)

        assert place(0.0, 0.0) == {"placement": {"from_peg_mm": 0, "turned_deg": 0, "peg_margin_mm": 7}}
        assert place(0.005, 90.0)["placement"] == {"from_peg_mm": 5, "turned_deg": 0, "peg_margin_mm": 2}
        fit = place(0.005, 20.0)["placement"]
        assert fit["turned_deg"] == 20 and fit["peg_margin_mm"] < 0
        assert place(0.2, 0.0) == {}
    finally:
        env.close()
