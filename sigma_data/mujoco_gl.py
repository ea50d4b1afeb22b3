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


class _BelowErrorFilter:
    """Drops robosuite log records below ERROR (its start-up notes about optional parts)."""

    def filter(self, record) -> bool:
        import logging

        return record.levelno >= logging.ERROR


_FILTER = _BelowErrorFilter()


def quiet_robosuite() -> None:
    """Silence robosuite's start-up warnings (no private macro file, robosuite_models, mink IK, controller
    parts a Panda does not have); errors still show.

    robosuite logs them through its own ``robosuite_logs`` logger, at import and at every ``suite.make``. A filter
    on that logger works before robosuite is imported (``import sigma_data`` installs it), so even the import-time
    notes disappear. ``SIGMA_ROBOSUITE_WARNINGS=1`` keeps them.
    """
    import logging

    if os.environ.get("SIGMA_ROBOSUITE_WARNINGS") == "1":
        return
    logger = logging.getLogger("robosuite_logs")
    if _FILTER not in logger.filters:
        logger.addFilter(_FILTER)
