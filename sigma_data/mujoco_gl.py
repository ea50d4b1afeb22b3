"""Choose the headless OpenGL backend for MuJoCo before robosuite or mujoco is imported.

Order: an explicit ``MUJOCO_GL`` in the environment wins; else the backend that ``make setup`` proved
working on this machine (recorded in ``<venv>/sigma_mujoco_gl``); else ``egl``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

_RECORD = Path(sys.prefix) / "sigma_mujoco_gl"


def configure_mujoco_gl() -> str:
    """Set ``MUJOCO_GL`` and ``PYOPENGL_PLATFORM`` (if unset) and return the backend in use."""
    backend = os.environ.get("MUJOCO_GL")
    if not backend:
        try:
            backend = _RECORD.read_text().strip() or "egl"
        except OSError:
            backend = "egl"
        os.environ["MUJOCO_GL"] = backend
    if backend in ("egl", "osmesa"):
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    return backend


def quiet_robosuite() -> None:
    """Silence robosuite's per-env start-up warnings (controller parts a Panda does not have, mink IK).

    robosuite logs them through its own ``robosuite_logs`` logger at every ``suite.make``; errors still show.
    """
    import logging

    logger = logging.getLogger("robosuite_logs")
    logger.setLevel(logging.ERROR)
    for handler in logger.handlers:
        handler.setLevel(logging.ERROR)
