"""Opening a sigma checkpoint safely: :func:`check_checkpoint` refuses files that would run code or hold broken
weights, :func:`load_policy` returns the policy with its saved processors. ``sigma-eval``, ``sigma-diagnose`` and
``sigma-viz policy`` open checkpoints only through here (README, "Opening checkpoints from others")."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")


class CheckpointError(ValueError):
    """A checkpoint that cannot be opened safely; the message names the file."""


def check_checkpoint(checkpoint: Path | str) -> None:
    """Refuse a checkpoint that cannot be evaluated safely, naming the file and what is wrong with it:

    * ``config.json`` missing, unreadable, or not a sigma policy;
    * a processor step named by import path (``"class": "module.Name"``) or unknown to LeRobot's processor
      registry. LeRobot imports and instantiates such a class with the saved config when it opens the
      checkpoint (``lerobot-eval`` too): a tampered JSON file could run any code. sigma's loaders accept only
      steps registered by LeRobot or sigma;
    * ``model.safetensors`` unreadable (truncated, corrupt) or holding a NaN/inf tensor.
    """
    from lerobot.processor.pipeline import ProcessorStepRegistry
    from safetensors import safe_open

    import sigma_policy  # noqa: F401  (registers sigma's processor steps)

    root = Path(checkpoint)
    config_path = root / "config.json"
    try:
        kind = json.loads(config_path.read_text()).get("type")
    except (OSError, ValueError) as e:
        raise CheckpointError(f"{config_path}: cannot read the policy config ({e})") from e
    if kind != "sigma":
        raise CheckpointError(f"{config_path}: a {kind!r} policy, not a sigma checkpoint")
    registered = set(ProcessorStepRegistry.list())
    for name in PROCESSOR_FILES:
        path = root / name
        try:
            steps = json.loads(path.read_text())["steps"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise CheckpointError(f"{path}: cannot read the processor steps ({e})") from e
        for i, step in enumerate(steps):
            if "class" in step or step.get("registry_name") not in registered:
                what = (
                    f"class {step['class']!r}" if "class" in step else f"step {step.get('registry_name')!r}"
                )
                raise CheckpointError(
                    f"{path}: step {i} names {what}, which is not a registered processor step; refusing to open "
                    "the checkpoint (opening it would import and run that class)"
                )
    model_path = root / "model.safetensors"
    try:
        with safe_open(model_path, "pt") as f:
            for key in f.keys():  # noqa: SIM118  (a safe_open handle is not iterable)
                tensor = f.get_tensor(key)
                if tensor.is_floating_point() and not bool(tensor.isfinite().all()):
                    raise CheckpointError(f"{model_path}: tensor {key!r} holds NaN or inf values")
    except CheckpointError:
        raise
    except Exception as e:  # safetensors raises its own error types for truncated or corrupt files
        raise CheckpointError(f"{model_path}: cannot read the weights ({type(e).__name__}: {e})") from e


def check_act_with_ema(checkpoint: Path | str) -> None:
    """ValueError naming ``checkpoint`` unless it was trained with a weight average (the policy's ``ema_decay``,
    docs/method.md §10.1): only then has ``--act_with_ema`` two sets of weights to choose between."""
    from sigma_policy.configuration_sigma import SigmaConfig

    if not SigmaConfig.from_pretrained(checkpoint).ema_decay:
        raise ValueError(f"--act_with_ema: {checkpoint} was trained without a weight average (ema_decay 0)")


def load_policy(checkpoint: Path | str, device: str = "cpu") -> tuple[Any, Any, Any]:
    """A saved sigma checkpoint on ``device`` in eval mode, with its saved pre- and post-processor
    (after :func:`check_checkpoint`)."""
    from lerobot.policies.factory import make_pre_post_processors

    from sigma_policy.modeling_sigma import SigmaPolicy

    check_checkpoint(checkpoint)
    policy = SigmaPolicy.from_pretrained(str(checkpoint))
    policy.config.device = device
    policy.to(device).eval()
    pre, post = make_pre_post_processors(
        policy.config,
        pretrained_path=str(checkpoint),
        preprocessor_overrides={"device_processor": {"device": device}},
    )
    return policy, pre, post
