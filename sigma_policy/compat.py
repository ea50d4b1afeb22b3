"""Reading checkpoints that earlier versions of sigma saved: options since removed, and modules since added.

**Removed options.** Each recipe experiment that did not help is written up in docs/learning.md, with its command
and numbers, and its option is then removed, so that :class:`~sigma_policy.configuration_sigma.SigmaConfig` lists
only what a user may want to set. A checkpoint saved while such an option existed still names it in its
``config.json`` (every field is saved, set or not). :func:`drop_retired` reads such a config:

* a retired field at the value that meant "off" is dropped: the checkpoint was trained as today's code trains it;
* a retired field at any other value is refused, with the field, its value and the docs/learning.md section that
  measured it. That checkpoint's network or inputs are not ones this code builds. The last commit that ran it is
  the option's ``commit`` (:data:`LAST_COMMIT` for those removed on 2026-11-30).

``SigmaConfig.from_pretrained`` (so ``SigmaPolicy.from_pretrained``: ``sigma-eval``, ``sigma-diagnose``, ``sigma-viz
policy``) and the benchmarks' reuse of a saved run (``pipelines/training.py``) read configs through it. Stock
``lerobot-eval`` parses a checkpoint's ``config.json`` itself and names a retired field as not valid for
``SigmaConfig``.

**Added modules.** A checkpoint saved before a module existed (``lang_film``, ``local_channels``, the proprio token's
position and orientation, the proprio input of the heads, ``proprio_film``) has no config field for it, so its
config resolves the field from today's preset; loading the file into a network with that module would leave the
module randomly initialised (LeRobot loads non-strictly). :func:`match_saved_modules` turns such fields off, with a
warning, from the tensors the file holds, and ``SigmaPolicy`` rebuilds its network to match before loading.

**Added options without weights.** An option that changes what the network reads but adds no tensor
(``lang_task_contrast``) cannot be told from the weights; a config saved before it existed does not name it, and
:func:`fill_added_off` reads it as off (the checkpoint was trained without it), not as today's preset. Stock
``lerobot-eval``, which parses ``config.json`` itself, reads such a config with today's preset.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sigma_policy.configuration_sigma import SigmaConfig

__all__ = [
    "ADDED_OFF",
    "LAST_COMMIT",
    "RETIRED",
    "Retired",
    "RetiredOptionError",
    "drop_retired",
    "fill_added_off",
    "match_saved_modules",
]

# The last commit of sigma whose code still has the options removed on 2026-11-30 (git checkout it to rerun their
# commands); an option removed later names its own (Retired.commit).
LAST_COMMIT = "6ce2291"

_ANY = object()  # an option that acted only through another retired one: any saved value is dropped


@dataclass(frozen=True)
class Retired:
    """A removed option: the section of docs/learning.md that measured it, the value that meant off (``_ANY`` for
    an option that acted only through another retired one) and the last commit of sigma that has it."""

    section: str
    off: Any = _ANY
    commit: str = LAST_COMMIT


_STEM = "PickPlace: a convolutional stem for the small objects, and the milk carton's ridge"
_HAND_MASK = "The hand hides what it is over"
_MARKER = "The hand marker: the hand back as a pixel, and what it teaches"
_ZOOM = "A zoomed second stage: one network at two scales"
_PADDING = "Padding states and Stack's order"
_SESSION_83 = "1c398d5"  # the last commit with lang_zero_padding and decoder_lang_film

RETIRED: dict[str, Retired] = {
    "stem_layers": Retired(_STEM, off=0),
    "hand_mask_box": Retired(_HAND_MASK, off=None),
    "hand_mask_views": Retired(_HAND_MASK),  # only with hand_mask_box
    "hand_marker": Retired(_MARKER, off=False),
    "hand_site_noise_m": Retired(_MARKER, off=0.0),
    "zoom_box_m": Retired(_ZOOM, off=0.0),
    "zoom_share": Retired(_ZOOM),  # these three only with zoom_box_m
    "zoom_jitter_m": Retired(_ZOOM),
    "zoom_at_inference": Retired(_ZOOM),
    "lang_zero_padding": Retired(_PADDING, off=False, commit=_SESSION_83),
    "decoder_lang_film": Retired(_PADDING, off=False, commit=_SESSION_83),
}


class RetiredOptionError(ValueError):
    """A saved config sets an option this version of sigma no longer has."""


def drop_retired(values: dict[str, Any], source: str) -> dict[str, Any]:
    """``values`` (a sigma policy config as JSON stores it) without the retired options; raises
    :class:`RetiredOptionError` naming ``source`` (the file), the field and its docs section when one of them is set
    to anything but off."""
    kept = {k: v for k, v in values.items() if k not in RETIRED}
    for name, value in values.items():
        option = RETIRED.get(name)
        if option is None or option.off is _ANY or _same(value, option.off):
            continue
        raise RetiredOptionError(
            f"{source}: policy.{name}={value!r} is an option sigma tried and removed (docs/learning.md "
            f'"{option.section}"): this version cannot build that policy; sigma at commit {option.commit} can'
        )
    return kept


# Options a preset turns on that add no weights, each at its "off" value (module docstring, "Added options without weights").
ADDED_OFF: dict[str, Any] = {"lang_task_contrast": False}


def fill_added_off(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` (a saved sigma policy config) with each option of :data:`ADDED_OFF` it does not name set off."""
    return {**ADDED_OFF, **values}


def _same(value: Any, off: Any) -> bool:
    if isinstance(off, bool) or off is None:
        return value is off
    return isinstance(value, (int, float)) and not isinstance(value, bool) and float(value) == float(off)


def match_saved_modules(cfg: SigmaConfig, model_file: str) -> None:
    """Turn off, with a warning, each module ``cfg`` asks for that the weights in ``model_file`` (safetensors) were
    saved without (module docstring, "Added modules")."""
    from safetensors import safe_open

    log = logging.getLogger(__name__)
    with safe_open(model_file, "pt") as f:
        names = set(f.keys())  # a safe_open handle is not iterable

        def width(key: str) -> int | None:
            return f.get_slice(key).get_shape()[1] if key in names else None

        saved_proprio = width("network.proprio_preprocess.linear.weight")
        saved_head = width("network.feat_fc.0.weight")
    if cfg.lang_film and not any(k.startswith("network.lang_film.") for k in names):
        log.warning("%s has no instruction-FiLM weights (saved before policy.lang_film existed)", model_file)
        cfg.lang_film = False
    if cfg.use_proprio and cfg.proprio_film and not any(k.startswith("network.proprio_film.") for k in names):
        log.warning("%s has no proprio-FiLM weights (saved before policy.proprio_film existed)", model_file)
        cfg.proprio_film = False
    if cfg.local_channels and not any(k.startswith("network.local_encoder.") for k in names):
        log.warning("%s has no local head features (saved before policy.local_channels existed)", model_file)
        cfg.local_channels = 0
    if saved_proprio is not None and saved_proprio < cfg.network_config().proprio_dim:
        log.warning(
            "%s has a %d-D proprio token (saved before policy.proprio_position/proprio_orientation existed)%s",
            model_file,
            saved_proprio,
            ": a gripper-only proprio token" if saved_proprio == 3 else "",
        )
        cfg.proprio_position = saved_proprio >= 6
        cfg.proprio_orientation = False
    if cfg.proprio_in_heads and saved_head is not None:
        net = cfg.network_config()
        if saved_head == net.num_views * (net.im_channels + net.final_dim + net.local_channels):
            log.warning(
                "%s has heads without the proprio input (saved before policy.proprio_in_heads)", model_file
            )
            cfg.proprio_in_heads = False
