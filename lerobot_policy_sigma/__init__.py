"""LeRobot plugin shim: LeRobot imports this distribution by name; importing it registers ``--policy.type=sigma``."""

import sigma_policy  # noqa: F401
