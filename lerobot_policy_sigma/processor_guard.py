"""Processor steps named by import path are refused when LeRobot opens a checkpoint in a process that loaded sigma's
plugin (``lerobot-eval``, ``lerobot-train --policy.path``, any policy, any env).

A saved processor (``policy_preprocessor.json`` / ``policy_postprocessor.json``) names each step either by its
registry name or, for a step class that is not registered, by import path (``"class": "module.Name"``). LeRobot
0.6.1 (``DataProcessorPipeline._resolve_step_class``) imports that module and instantiates the class with the saved
config: a tampered file (``{"class": "subprocess.Popen", "config": {"args": [...]}}``) runs code on this machine
as the checkpoint opens. sigma's own loaders refuse such steps before anything is imported
(``pipelines/checkpoints.py``); this guard applies the same rule inside LeRobot's loader:

* a step named by registry name is LeRobot's business, unchanged (an unknown name is already LeRobot's error, and
  nothing is imported for it);
* a step named by the import path of a class that is registered (already imported) resolves as before;
* any other import path is refused with an ``ImportError`` naming the class, before the module is imported.

What it costs: a checkpoint whose processor uses an unregistered step class of your own no longer opens in a
process that loaded sigma's plugin. Register the step (``@ProcessorStepRegistry.register``) or, for a file you
trust, set ``SIGMA_NO_LEROBOT_PATCHES=1`` (which leaves LeRobot untouched).
"""

from __future__ import annotations

import os
from typing import Any

_INSTALLED = False


def _registered_paths() -> set[str]:
    from lerobot.processor.pipeline import ProcessorStepRegistry

    paths = set()
    for name in ProcessorStepRegistry.list():
        cls = ProcessorStepRegistry.get(name)
        paths.add(f"{cls.__module__}.{cls.__qualname__}")
    return paths


def _guarded_resolve(cls: type, step_entry: dict[str, Any]) -> tuple[type, str]:
    if isinstance(step_entry, dict) and "registry_name" not in step_entry and "class" in step_entry:
        path = step_entry["class"]
        if path not in _registered_paths():
            raise ImportError(
                f"refusing processor step class {path!r}: it is not a registered processor step, and opening it "
                "would import and run that class (a checkpoint's processor JSON can name any class). Register the "
                "step with @ProcessorStepRegistry.register, or set SIGMA_NO_LEROBOT_PATCHES=1 for a file you trust "
                "(lerobot_policy_sigma/processor_guard.py)"
            )
    return _guarded_resolve.original.__func__(cls, step_entry)


def install() -> bool:
    """Guard LeRobot's processor step resolution (idempotent). Returns whether the guard is active."""
    global _INSTALLED
    if _INSTALLED:
        return True
    if os.environ.get("SIGMA_NO_LEROBOT_PATCHES"):
        return False
    try:
        from lerobot.processor.pipeline import DataProcessorPipeline
    except ImportError:
        return False
    original = DataProcessorPipeline.__dict__.get("_resolve_step_class")
    if not isinstance(original, classmethod):  # another LeRobot: leave it alone
        return False
    _guarded_resolve.original = original
    DataProcessorPipeline._resolve_step_class = classmethod(_guarded_resolve)
    _INSTALLED = True
    return True
