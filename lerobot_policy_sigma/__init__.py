"""LeRobot plugin shim: LeRobot imports this distribution by name at start-up.

Importing it registers ``--policy.type=sigma`` (``sigma_policy``) and ``--env.type=sigma_robosuite``
(``sigma_data.lerobot_env``) with LeRobot's config registries, and installs sigma's result-identical speed fix for
LeRobot's multi-frame dataset reads (``sigma_policy/lerobot_patches.py``; ``SIGMA_NO_LEROBOT_PATCHES=1`` leaves
LeRobot untouched) before ``lerobot-train`` opens the dataset, so its spawned DataLoader workers get it too.
"""

import sigma_data.lerobot_env  # noqa: F401
import sigma_policy  # noqa: F401
from sigma_policy import lerobot_patches

lerobot_patches.install()
