"""``--env.type=sigma_robosuite`` for the stock ``lerobot-eval`` (and in-training eval of ``lerobot-train``).

LeRobot imports the ``lerobot_policy_sigma`` distribution at start-up; its shim imports this module, which
registers the env config with LeRobot and the gym id with gymnasium. Example::

    lerobot-eval --policy.path=outputs/train/checkpoints/last/pretrained_model \\
        --env.type=sigma_robosuite --env.task=stack:green_on_red \\
        --eval.n_episodes=10 --eval.batch_size=1 --policy.device=cpu

``--env.task`` is a task (variations round-robin over episode seeds) or ``task:variation``.

``--env.control=dense`` evaluates stock LeRobot policies (ACT, Diffusion Policy, ...) trained on the dense
dataset: one 7-D OSC_POSE action per 20 Hz step, the task's own step limit, observations named like the dense
dataset's; ``--env.depth=false`` leaves depth out (an RGB-only dense dataset, ``sigma-data collect
--output.dense_depth=false``)::

    lerobot-eval --policy.path=outputs/act/checkpoints/last/pretrained_model \
        --env.type=sigma_robosuite --env.control=dense --env.depth=false --env.task=lift \
        --env.image_size=64 --eval.n_episodes=10 --eval.batch_size=1 --policy.device=cpu
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

from sigma_data.cameras import DEFAULT_CAMERAS
from sigma_data.contract import FPS as DENSE_FPS  # robosuite's control frequency, the dense dataset's fps

ENV_TYPE = "sigma_robosuite"
KEYFRAME_FPS = 2  # nominal: one keyframe step is several control steps; only rollout videos use it
KEYFRAME_EPISODE_LENGTH = 10


@EnvConfig.register_subclass(ENV_TYPE)
@dataclass
class SigmaRobosuiteEnvConfig(EnvConfig):
    """A sigma task in robosuite: one 9-D keyframe action per env step, or (``control="dense"``) one 7-D
    OSC_POSE control step."""

    task: str | None = "lift"
    # "keyframe" (sigma's 9-D next-keyframe pose) or "dense" (the dense dataset's 7-D OSC_POSE delta, 20 Hz).
    control: str = "keyframe"
    # Frames per second of the rollout videos; 0 = 2 (one keyframe is several control steps) or 20 (dense).
    fps: int = 0
    # Steps before the episode is cut; 0 = 10 keyframes, or the task's max_steps control steps (dense).
    episode_length: int = 0
    cameras: tuple[str, ...] = DEFAULT_CAMERAS
    image_size: int = 128
    # Depth observations images.<cam>_depth (false for a policy trained on an RGB-only dense dataset).
    depth: bool = True
    # Unit of the depth observations: "mm" like stock LeRobotDataset's default read-back, or "m".
    depth_unit: str = "mm"
    render_mode: str = "rgb_array"
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from sigma_data.sim_env import ACTION_NAMES, parse_task

        if self.control not in ACTION_NAMES:
            raise ValueError(f"--env.control must be one of {sorted(ACTION_NAMES)}, got {self.control!r}")
        if not self.fps:
            self.fps = DENSE_FPS if self.control == "dense" else KEYFRAME_FPS
        if not self.episode_length:
            task = parse_task(self.task or "lift")[0]
            self.episode_length = task.max_steps if self.control == "dense" else KEYFRAME_EPISODE_LENGTH
        s = self.image_size
        self.features[ACTION] = PolicyFeature(
            type=FeatureType.ACTION, shape=(len(ACTION_NAMES[self.control]),)
        )
        self.features["agent_pos"] = PolicyFeature(type=FeatureType.STATE, shape=(10,))
        self.features_map.setdefault(ACTION, ACTION)
        self.features_map.setdefault("agent_pos", OBS_STATE)
        for cam in self.cameras:
            self.features[f"pixels/{cam}"] = PolicyFeature(type=FeatureType.VISUAL, shape=(s, s, 3))
            self.features_map.setdefault(f"pixels/{cam}", f"{OBS_IMAGES}.{cam}")
            if self.depth:
                self.features[f"images.{cam}_depth"] = PolicyFeature(type=FeatureType.VISUAL, shape=(1, s, s))
                self.features_map.setdefault(f"images.{cam}_depth", f"{OBS_IMAGES}.{cam}_depth")
            for part, shape in (("intrinsics", (3, 3)), ("extrinsics", (4, 4))):
                key = f"camera.{cam}.{part}"
                self.features[key] = PolicyFeature(type=FeatureType.STATE, shape=shape)
                self.features_map.setdefault(key, f"observation.{key}")

    @property
    def package_name(self) -> str:
        return "sigma_data.sim_env"

    @property
    def gym_id(self) -> str:
        from sigma_data.sim_env import GYM_ID

        return GYM_ID

    @property
    def gym_kwargs(self) -> dict:
        return {
            "task": self.task,
            "cameras": tuple(self.cameras),
            "image_size": self.image_size,
            "render_mode": self.render_mode,
            "depth_unit": self.depth_unit,
            "control": self.control,
            "depth": self.depth,
            "max_episode_steps": self.episode_length,
        }
