"""sigma_data: robosuite demonstrations into LeRobot v3 datasets with depth, calibration and keyframes."""

from sigma_data.mujoco_gl import configure_mujoco_gl, quiet_robosuite

MUJOCO_GL = configure_mujoco_gl()
quiet_robosuite()

__all__ = ["MUJOCO_GL"]
