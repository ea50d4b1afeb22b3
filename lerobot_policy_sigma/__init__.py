"""LeRobot plugin shim: LeRobot imports this distribution by name at start-up.

Importing it registers ``--policy.type=sigma`` (``sigma_policy``) and ``--env.type=sigma_robosuite``
(``sigma_data.lerobot_env``) with LeRobot's config registries.
"""

import sigma_data.lerobot_env  # noqa: F401
import sigma_policy  # noqa: F401
