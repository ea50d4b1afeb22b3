"""ReplayRenderer / RenderedFrames: threaded replay renders exactly what CameraRig renders, from the scene of the
episode even after the env has moved on."""

import numpy as np
import pytest

from sigma_data.cameras import DEFAULT_CAMERAS, CameraRig, RenderConfig
from sigma_data.record import EpisodeRecorder
from sigma_data.replay_render import RenderedFrames, ReplayRenderer
from sigma_data.suite import close_env, get_task, make_env, reset_env

SIZE = 64


def record(env, task, seed: int, steps: int = 8):
    reset_env(env, task, task.variations[0], seed=seed)
    rec = EpisodeRecorder(env)
    for i in range(steps):
        rec.step(np.array([0.5, 0.2 * (-1) ** i, 0.4, 0, 0, 0.3, -1.0]))
    return rec.to_episode(task.name, task.variations[0].name, "replay test", seed)


def assert_same_views(a, b, where: str) -> None:
    assert list(a) == list(b), where
    for cam in a:
        for field in ("rgb", "depth", "intrinsics", "extrinsics"):
            np.testing.assert_array_equal(
                getattr(a[cam], field), getattr(b[cam], field), err_msg=f"{where} {cam}"
            )


@pytest.fixture(scope="module")
def lift():
    task = get_task("lift")
    env = make_env(task, cameras=DEFAULT_CAMERAS, height=SIZE, width=SIZE)
    rig = CameraRig(env, RenderConfig(DEFAULT_CAMERAS, SIZE, SIZE))
    with ReplayRenderer(rig, threads=2) as replay:
        yield task, env, rig, replay
    close_env(env)


def test_threads_render_what_the_rig_renders_bit_for_bit(lift):
    task, env, rig, replay = lift
    ep = record(env, task, seed=1)
    expected = [rig.render_state(s) for s in ep.sim_states]
    order = list(range(len(ep)))
    with RenderedFrames(ep, rig, order=order, replay=replay, ahead=3) as frames:
        for t in order:
            assert_same_views(frames(t), expected[t], f"frame {t}")
        assert frames.count == len(ep) and frames.seconds > 0 and not frames.pending
    # A frame asked for out of order (not in `order`) renders at once; kept frames render once.
    with RenderedFrames(ep, rig, keep={2}, replay=replay) as frames:
        assert_same_views(frames(2), expected[2], "frame 2")
        assert frames(2) is frames(2) and frames.count == 1


def test_the_snapshot_keeps_the_episode_scene_after_the_env_moves_on():
    task = get_task("door")  # reset moves the door frame (model body_pos), not only the state
    env = make_env(task, cameras=("agentview",), height=SIZE, width=SIZE)
    try:
        rig = CameraRig(env, RenderConfig(("agentview",), SIZE, SIZE))
        with ReplayRenderer(rig, threads=1) as replay:
            ep = record(env, task, seed=3, steps=3)
            expected = [rig.render_state(s) for s in ep.sim_states]
            snapshot = replay.snapshot()
            frame_pos = env.sim.model._model.body_pos.copy()
            reset_env(env, task, task.variations[0], seed=4)
            assert not np.array_equal(frame_pos, env.sim.model._model.body_pos)
            with RenderedFrames(ep, rig, order=range(len(ep)), replay=replay, snapshot=snapshot) as frames:
                for t in range(len(ep)):
                    assert_same_views(frames(t), expected[t], f"door frame {t}")
    finally:
        close_env(env)


def test_close_cancels_what_was_not_asked_for(lift):
    task, env, rig, replay = lift
    ep = record(env, task, seed=2, steps=12)
    frames = RenderedFrames(ep, rig, order=range(len(ep)), replay=replay, ahead=6)
    frames(0)
    in_flight = list(frames.pending.values())
    assert len(in_flight) == 6
    frames.close()
    assert not frames.pending and all(f.done() for f in in_flight)  # nothing left rendering this episode
    assert any(f.cancelled() for f in in_flight)  # the frames still queued were dropped, not rendered
    with RenderedFrames(ep, rig, order=[5], replay=replay) as again:
        assert_same_views(again(5), rig.render_state(ep.sim_states[5]), "after close")


def test_bad_input_is_named(lift):
    task, env, rig, replay = lift
    ep = record(env, task, seed=2, steps=2)
    with pytest.raises(ValueError, match="threads"):
        ReplayRenderer(rig, threads=0)
    with pytest.raises(ValueError, match="sim state has shape"):
        replay.submit(replay.snapshot(), np.zeros(3))
    with (
        RenderedFrames(ep, rig, replay=replay) as frames,
        pytest.raises(IndexError, match=f"{ep.name}: frame 99"),
    ):
        frames(99)
