"""Configuration of the Σ-agent policy (registered with LeRobot as ``--policy.type=sigma``).

Placeholder of the foundation issue: the full paper/small configurations arrive with the network.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import NormalizationMode
from lerobot.optim.optimizers import AdamConfig


@PreTrainedConfig.register_subclass("sigma")
@dataclass
class SigmaConfig(PreTrainedConfig):
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.IDENTITY,
        }
    )
    push_to_hub: bool = False
    optimizer_lr: float = 1e-4

    def __post_init__(self):
        super().__post_init__()

    @property
    def observation_delta_indices(self) -> list[int]:
        return [0, 1]

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(lr=self.optimizer_lr)

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        return None
