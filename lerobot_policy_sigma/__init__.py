"""LeRobot plugin shim: LeRobot imports this distribution by name at start-up.

Importing it registers ``--policy.type=sigma`` (``sigma_policy``) and ``--env.type=sigma_robosuite``
(``sigma_data.lerobot_env``) with LeRobot's config registries, and installs sigma's result-identical speed fix for
LeRobot's multi-frame dataset reads (``sigma_policy/lerobot_patches.py``; ``SIGMA_NO_LEROBOT_PATCHES=1`` leaves
LeRobot untouched) before ``lerobot-train`` opens the dataset, so its spawned DataLoader workers get it too. It also
makes LeRobot refuse processor steps named by the import path of an unregistered class when it opens a checkpoint
(``lerobot_policy_sigma/processor_guard.py``: such a step would import and run any class a tampered file names).
"""

import sigma_data.lerobot_env  # noqa: F401
import sigma_policy  # noqa: F401
from lerobot_policy_sigma import processor_guard
from sigma_policy import lerobot_patches

lerobot_patches.install()
processor_guard.install()
