"""``--env.type=sigma_robosuite`` for the stock ``lerobot-eval`` (and in-training eval of ``lerobot-train``).

LeRobot imports the ``lerobot_policy_sigma`` distribution at start-up; its shim imports this module, which
registers the env config with LeRobot and the gym id with gymnasium. Example::

    lerobot-eval --policy.path=outputs/train/checkpoints/last/pretrained_model \\
        --env.type=sigma_robosuite --env.task=stack:green_on_red \\
        --eval.n_episodes=10 --eval.batch_size=1 --policy.device=cpu

``--env.task`` is a task (variations round-robin over episode seeds) or ``task:variation``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

from sigma_data.cameras import DEFAULT_CAMERAS

ENV_TYPE = "sigma_robosuite"


@EnvConfig.register_subclass(ENV_TYPE)
@dataclass
class SigmaRobosuiteEnvConfig(EnvConfig):
    """A sigma task in robosuite, one 9-D keyframe action per env step."""

    task: str | None = "lift"
    # Nominal: one step is one keyframe (several control steps); only videos use it.
    fps: int = 2
    # Keyframes the policy may take before the episode is cut.
    episode_length: int = 10
    cameras: tuple[str, ...] = DEFAULT_CAMERAS
    image_size: int = 128
    # Unit of the depth observations: "mm" like stock LeRobotDataset's default read-back, or "m".
    depth_unit: str = "mm"
    render_mode: str = "rgb_array"
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        s = self.image_size
        self.features[ACTION] = PolicyFeature(type=FeatureType.ACTION, shape=(9,))
        self.features["agent_pos"] = PolicyFeature(type=FeatureType.STATE, shape=(10,))
        self.features_map.setdefault(ACTION, ACTION)
        self.features_map.setdefault("agent_pos", OBS_STATE)
        for cam in self.cameras:
            self.features[f"pixels/{cam}"] = PolicyFeature(type=FeatureType.VISUAL, shape=(s, s, 3))
            self.features[f"images.{cam}_depth"] = PolicyFeature(type=FeatureType.VISUAL, shape=(1, s, s))
            self.features_map.setdefault(f"pixels/{cam}", f"{OBS_IMAGES}.{cam}")
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
            "max_episode_steps": self.episode_length,
        }
