"""sigma_policy: the Σ-agent policy as a LeRobot policy plugin (``--policy.type=sigma``)."""

from sigma_policy.configuration_sigma import SigmaConfig

__all__ = ["SigmaConfig"]
