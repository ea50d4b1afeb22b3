"""sigma_policy: the Σ-agent policy as a LeRobot policy plugin (``--policy.type=sigma``).

Importing the package only registers names with LeRobot's registries, as LeRobot's own policies do: the policy
type ``sigma``, the optimiser ``lamb`` and the processor step ``sigma_calibration_batch`` (needed to reload saved
pre-processors). It changes nothing in LeRobot: the result-identical speed fix for LeRobot's multi-frame dataset
reads (:mod:`sigma_policy.lerobot_patches`) is installed where LeRobot reads sigma's data -- by the plugin entry
point that ``lerobot-train``/``lerobot-eval`` load (``lerobot_policy_sigma``) and when a ``SigmaPolicy`` is built
-- or by calling ``sigma_policy.lerobot_patches.install()``. ``SigmaPolicy`` is imported on first use.
"""

from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.lamb import Lamb, LambConfig
from sigma_policy.processor_sigma import SigmaCalibrationBatchStep, make_sigma_pre_post_processors

__all__ = [
    "Lamb",
    "LambConfig",
    "SigmaCalibrationBatchStep",
    "SigmaConfig",
    "SigmaPolicy",
    "make_sigma_pre_post_processors",
]


def __getattr__(name: str):
    if name == "SigmaPolicy":
        from sigma_policy.modeling_sigma import SigmaPolicy

        return SigmaPolicy
    raise AttributeError(f"module 'sigma_policy' has no attribute {name!r}")
