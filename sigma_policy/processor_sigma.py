"""Pre/post-processors of the sigma policy (resolved by LeRobot as ``make_sigma_pre_post_processors``).

Preprocessor: rename -> add batch dim (LeRobot's step, then ``SigmaCalibrationBatchStep`` for the 3x3 / 4x4
camera matrices that LeRobot's step leaves alone) -> device -> normaliser restricted to
``config.normalize_observation_keys`` (default ``observation.state`` only, and IDENTITY by default), so depth,
intrinsics and extrinsics always reach the policy un-normalised.
Postprocessor: unnormaliser (IDENTITY for the 9-D world-frame action by default) -> CPU.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature
from lerobot.processor import PolicyProcessorPipeline
from lerobot.processor.factory import make_default_policy_processor_steps, make_policy_processor_pipelines
from lerobot.processor.pipeline import ObservationProcessorStep, ProcessorStepRegistry
from torch import Tensor

from sigma_data.contract import CALIBRATION_PREFIX
from sigma_policy.configuration_sigma import SigmaConfig

CALIBRATION_ITEM_NDIM = 2  # (3, 3) intrinsics and (4, 4) extrinsics


@dataclass
@ProcessorStepRegistry.register(name="sigma_calibration_batch")
class SigmaCalibrationBatchStep(ObservationProcessorStep):
    """Add a batch dimension to unbatched ``observation.camera.*`` matrices (single-observation inference)."""

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        out = dict(observation)
        for key, value in observation.items():
            is_matrix = isinstance(value, Tensor) and value.dim() == CALIBRATION_ITEM_NDIM
            if key.startswith(CALIBRATION_PREFIX) and is_matrix:
                out[key] = value.unsqueeze(0)
        return out

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features


def make_sigma_pre_post_processors(
    config: SigmaConfig, dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None
) -> tuple[PolicyProcessorPipeline, PolicyProcessorPipeline]:
    steps = make_default_policy_processor_steps(config, dataset_stats)
    steps.normalize.normalize_observation_keys = set(config.normalize_observation_keys)
    return make_policy_processor_pipelines(
        input_steps=[
            steps.rename_observations,
            steps.add_batch_dim,
            SigmaCalibrationBatchStep(),
            steps.to_device,
            steps.normalize,
        ],
        output_steps=[steps.unnormalize, steps.to_cpu],
    )
