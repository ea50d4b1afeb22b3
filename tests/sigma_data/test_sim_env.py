"""The keyframe gym env: observation contract, expert-keyframe replay succeeds, LeRobot env config."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from sigma_data.control import EnvDriver
from sigma_data.sim_env import GYM_ID, SigmaRobosuiteEnv, parse_task
from sigma_data.suite import get_task, get_variation, make_env, reset_env

CAMS = ("agentview", "robot0_eye_in_hand")


def run_expert(task_name: str, variation: str, seed: int, make_driver):
    """Run a scripted expert through the driver ``make_driver(env)`` (an EnvDriver or an EpisodeRecorder)."""
    task = get_task(task_name)
    var = get_variation(task, variation)
    env = make_env(task)
    try:
        reset_env(env, task, var, seed)
        driver = make_driver(env)
        task.expert(driver, var, np.random.default_rng(seed))
        assert task.success(env, var), "the expert itself failed on this seed"
        return driver
    finally:
        env.close()


def expert_keyframes(task_name: str, variation: str, seed: int) -> np.ndarray:
    return np.asarray(run_expert(task_name, variation, seed, EnvDriver).keyframes)


@pytest.fixture(scope="module")
def lift_env():
    env = SigmaRobosuiteEnv("lift", cameras=CAMS, image_size=48, depth_unit="m")
    yield env
    env.close()


def test_observation_follows_the_data_contract(lift_env):
    obs, info = lift_env.reset(seed=3)
    assert lift_env.observation_space.contains(obs)
    assert info["variation"] == "lift_cube" and lift_env.task_description == "lift the cube"
    assert obs["pixels"]["agentview"].shape == (48, 48, 3)
    depth = obs["images.agentview_depth"]
    assert depth.shape == (1, 48, 48) and 0.3 < np.median(depth) < 3.0
    R = obs["camera.agentview.extrinsics"][:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-5)
    # the state is the grip site, gripper open after reset
    assert obs["agent_pos"].shape == (10,) and obs["agent_pos"][7] == 1.0
    assert lift_env.render().shape == (48, 48, 3)


def test_replaying_expert_keyframes_succeeds(lift_env):
    keyframes = expert_keyframes("lift", "lift_cube", seed=5)
    lift_env.reset(seed=5)
    terminated = False
    for kf in keyframes:
        _, reward, terminated, _, info = lift_env.step(kf)
        if terminated:
            break
    assert terminated and info["is_success"] and reward == 1.0


def test_bad_actions_and_names_are_clear_errors(lift_env):
    lift_env.reset(seed=0)
    with pytest.raises(ValueError, match="9 finite values"):
        lift_env.step(np.full(9, np.nan))
    with pytest.raises(ValueError, match="unknown task 'juggle'"):
        parse_task("juggle")
    with pytest.raises(ValueError, match="unknown variation 'blue_on_red'"):
        parse_task("stack:blue_on_red")


def test_variations_round_robin_over_seeds_and_depth_defaults_to_lerobot_mm():
    env = SigmaRobosuiteEnv("stack", cameras=("agentview",), image_size=32)
    try:
        names = {env.reset(seed=s)[1]["variation"] for s in range(2)}
        assert names == {"red_on_green", "green_on_red"}
        obs, _ = env.reset(seed=0)
        assert 300 < np.median(obs["images.agentview_depth"]) < 3000  # millimetres, like LeRobotDataset
    finally:
        env.close()


def test_lerobot_env_config_builds_the_vector_env():
    from lerobot.envs.configs import EnvConfig
    from lerobot.envs.factory import make_env as lerobot_make_env
    from lerobot.envs.utils import preprocess_observation

    import sigma_data.lerobot_env  # noqa: F401  (registers the env type, as the plugin shim does)

    cfg_cls = EnvConfig.get_choice_class("sigma_robosuite")
    cfg = cfg_cls(task="lift", cameras=CAMS, image_size=32, episode_length=4)
    assert cfg.gym_id == GYM_ID and GYM_ID in gym.registry
    envs = lerobot_make_env(cfg, n_envs=1)
    vec = envs["sigma_robosuite"][0]
    try:
        obs, _ = vec.reset(seed=[1])
        batch = preprocess_observation(obs)
        assert batch["observation.images.agentview"].shape == (1, 3, 32, 32)
        assert batch["observation.images.agentview_depth"].shape == (1, 1, 32, 32)
        assert batch["observation.camera.robot0_eye_in_hand.extrinsics"].shape == (1, 4, 4)
        assert batch["observation.state"].shape == (1, 10)
        assert vec.call("_max_episode_steps")[0] == 4
        assert list(vec.call("task_description")) == ["lift the cube"]
    finally:
        vec.close()


def expert_dense_episode(task_name: str, variation: str, seed: int):
    from sigma_data.record import EpisodeRecorder

    recorder = run_expert(task_name, variation, seed, EpisodeRecorder)
    instruction = get_variation(get_task(task_name), variation).instruction
    return recorder.to_episode(task_name, variation, instruction, seed)


def test_dense_control_replays_the_recorded_expert_actions_to_success():
    """The dense mode executes the dense dataset's 7-D actions step for step: the expert's recorded actions,
    replayed open loop from the same seed, succeed, and the observed states are the recorded states."""
    episode = expert_dense_episode("lift", "lift_cube", seed=5)
    env = SigmaRobosuiteEnv("lift", cameras=("agentview",), image_size=32, control="dense", depth=False)
    try:
        obs, _ = env.reset(seed=5)
        assert env.action_space.shape == (7,) and "images.agentview_depth" not in obs
        assert env.observation_space.contains(obs)
        states = [obs["agent_pos"]]
        terminated = False
        for action in episode.actions[:-1]:
            obs, reward, terminated, _, info = env.step(action)
            states.append(obs["agent_pos"])
            if terminated:
                break
        assert terminated and info["is_success"] and reward == 1.0 and info["control_steps"] == 1
        n = len(states)
        np.testing.assert_allclose(np.stack(states), episode.states[:n], atol=1e-5)
        with pytest.raises(ValueError, match="dense control: action must be 7 finite values"):
            env.step(np.zeros(9))
    finally:
        env.close()


def test_dense_lerobot_env_config_has_the_dense_dataset_features():
    from lerobot.envs.configs import EnvConfig

    import sigma_data.lerobot_env  # noqa: F401

    cfg = EnvConfig.get_choice_class("sigma_robosuite")(task="stack", control="dense", depth=False)
    assert cfg.features["action"].shape == (7,) and cfg.fps == 20
    assert cfg.episode_length == get_task("stack").max_steps
    assert not any(k.endswith("_depth") for k in cfg.features)
    keyframe = EnvConfig.get_choice_class("sigma_robosuite")(task="lift")
    assert keyframe.features["action"].shape == (9,) and keyframe.episode_length == 10 and keyframe.fps == 2
    with pytest.raises(ValueError, match="control must be one of"):
        EnvConfig.get_choice_class("sigma_robosuite")(control="joint")


def test_an_env_made_after_another_was_closed_renders_the_same_scene():
    """robosuite frees a closed env's render context when the context is collected, in whichever GL context is
    current then: the old env, dropped once its successor existed (``env = SigmaRobosuiteEnv(...)`` again), deleted
    the new env's textures and framebuffers, which then rendered noise. ``close`` frees it in its own context."""
    import gc

    env = SigmaRobosuiteEnv("lift", cameras=CAMS, image_size=32)
    first = env.reset(seed=0)[0]
    env.close()
    env = SigmaRobosuiteEnv("lift", cameras=CAMS, image_size=32)  # the closed env is dropped only now
    try:
        gc.collect()
        second = env.reset(seed=0)[0]
    finally:
        env.close()
    for cam in CAMS:
        np.testing.assert_array_equal(first["pixels"][cam], second["pixels"][cam], err_msg=cam)
        np.testing.assert_array_equal(
            first[f"images.{cam}_depth"], second[f"images.{cam}_depth"], err_msg=cam
        )


@pytest.mark.parametrize("how", ["closed", "dropped without close"])
def test_one_env_going_leaves_another_live_envs_rendering_intact(how: str):
    """Two envs alive, the second renders, then the first is closed (or only dropped) and collected: the second
    renders what it did."""
    import gc

    a = SigmaRobosuiteEnv("lift", cameras=CAMS, image_size=32)
    b = SigmaRobosuiteEnv("lift", cameras=CAMS, image_size=32)
    try:
        a.reset(seed=0)
        before = b.reset(seed=1)[0]
        if how == "closed":
            a.close()
        del a
        gc.collect()
        after = b.reset(seed=1)[0]
        for cam in CAMS:
            np.testing.assert_array_equal(before["pixels"][cam], after["pixels"][cam], err_msg=cam)
    finally:
        b.close()
