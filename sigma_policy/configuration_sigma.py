"""Configuration of the Σ-agent policy, registered with LeRobot as ``--policy.type=sigma``.

Presets (``--policy.preset=paper|small|suite|gpu``): the ``PRESETS`` table below, set side by side in
docs/method.md §12. Every architecture / schedule field left unset (``None``) is filled from the preset in
``__post_init__``; a field given explicitly (CLI or ``config.json``) always wins.

``paper`` is the paper's network and schedule (docs/method.md §5, §10). ``small`` is the network for 2 CPU cores
and minutes: 64² views of 8 × 8 tokens, 128-d attention in 4 layers, the proprio token (and its FiLM),
full-resolution local features for the heads, LeakyReLU heads, lr 1e-2 with biases, norms and query tokens exempt
from LAMB's trust ratio, yaw augmentation only, the views' heatmaps lifted to the 3D point by their product, and
each task's instructions contrasted (``lang_task_contrast``: the float32 demo's 700 steps read Stack's order with it,
64/100 and 61/100 against 42/100 and 38/100; docs/learning.md "Stack's order in 700 steps").

``suite`` is ``small`` for several tasks at once: ``per_task_bounds=True`` (each task rendered in its own box),
``yaw_scan_px=24`` (the rotation-equivariant yaw scan), lr 3e-3 and a 7500-step decay, without the instruction
contrast (not measured there). It is the suite benchmark's recipe (``benchmarks/bench_suite.py``; RESULTS.md "The
suite on 2 CPU cores"): on four tasks ``small``'s lr 1e-2 underfit with its 2000-step decay and diverged with a
longer one, and the scan lifted NutAssembly from 2/80 to 15/80.
On PickPlace alone (100 demonstrations per variation, 6000 steps) it scored 28/80 against ``small``'s 20/80, and
``small`` with the scan but lr 1e-2 9/80 (single runs; docs/learning.md "PickPlace: why the grasps miss").

``gpu`` is ``suite`` with a wider network for one GPU: ``im_channels``/``final_dim`` 32, attention 256-d in 8 heads of
32, 4 fusion layers (7.6 M parameters against 1.6 M) and the decay over 3000 steps, trained at ``--batch_size=64
--steps=3000``. On one NVIDIA H200 it trained in 7 minutes and scored 110/180 on the suite against 93/180 for
``suite`` at the same batch and schedule (seed 0, single runs; docs/gpu.md "The gpu preset"). On 2 CPU cores a step
costs about 2.3 times ``suite``'s.

LeRobot's cosine schedule shrinks warm-up and decay to the run's ``--steps`` when the run is shorter than the decay.

The small recipe is measured, not argued (``docs/learning.md``; ``RESULTS.md`` "Learning" from
``python -m benchmarks.bench_learning``): the previous small preset (lr 3e-3, trust ratio on every tensor, ±12.5 cm
/ ±45° augmentation) underfit and repeated the grasp keyframe; lr 1e-2 with the trust-ratio exemption lifts the
cube in every held-out episode after 600 steps; ReLU heads died at lr 1e-2 on Lift + Stack (gripper at chance for
1500 steps), LeakyReLU heads learned. Yaw augmentation alone made Stack worse (the heads could not tell the turned
scene's gripper orientation, nor keep the instruction); with the gripper's orientation in the proprio token, the
proprio vector in the heads and the heads' local features it lifted Stack from about a third to 90% of held-out
episodes at the same budget. The paper preset keeps RVT's augmentation and ReLU heads for its 25 K-step GPU schedule.

``paper`` has 38.26 M parameters with the contrastive heads and 36.03 M at inference (with 77 x 512 CLIP tokens;
the default MiniLM text encoder's 384-d tokens make it 0.34 % smaller).

Where the paper and the released code disagree, each choice that matters is a field, and docs/method.md §13.1 numbers
them with sigma's default and the reason: the queries (``num_queries``, ``query_attention``), λ (``bc_lambda``),
the negatives (``mask_same_instruction``, ``mask_same_task``), proprioception (``use_proprio``, ``proprio_*``), the
temperature (``logit_scale_init``, ``logit_scale_max``), the projection heads (``projection_activation``), the
evaluation box (``place_with_mean_at_eval``) and the heatmap's gradient (``detach_heatmap_for_features``). sigma's
own additions, each off in ``paper``, are in §13.2.

Inputs per camera ``<cam>`` in ``cameras`` (all cameras that have them when ``cameras`` is empty):
``observation.images.<cam>`` (RGB in [0,1]), ``observation.images.<cam>_depth`` (depth, unit ``depth_unit``),
``observation.camera.<cam>.intrinsics`` (3x3) and ``.extrinsics`` (4x4, camera-to-world, OpenCV axes); the
instruction arrives as ``task``. Output: ``action`` (9,) = [x, y, z, qx, qy, qz, qw, gripper_open,
ignore_collision], an absolute world-frame next-keyframe pose (quaternion xyzw, w >= 0).
"""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import draccus
from huggingface_hub.constants import CONFIG_NAME
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode
from lerobot.optim.schedulers import CosineDecayWithWarmupSchedulerConfig

from sigma_data.contract import (  # the data contract: the only sigma_data module the policy uses
    DEPTH_SUFFIX,
    IMAGE_PREFIX,
    KEYFRAME_ACTION_DIM,
    depth_key,
    extrinsics_key,
    intrinsics_key,
    recorded_bounds,
    recorded_instruction_bounds,
    recorded_instruction_tasks,
    rgb_key,
)
from sigma_policy.compat import drop_retired, fill_added_off
from sigma_policy.heatmap import check_heatmap_fusion
from sigma_policy.instruction_contrast import check_contrast_weight
from sigma_policy.lamb import LambConfig
from sigma_policy.network_config import NetworkConfig
from sigma_policy.test_time import check_yaw_angles
from sigma_policy.views import VIEW_NAMES, view_indices
from sigma_policy.weight_average import check_ema_decay

PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        "img_size": 220,
        "patch_size": 11,
        "im_channels": 64,
        "final_dim": 64,
        "attn_dim": 512,
        "attn_heads": 8,
        "attn_dim_head": 64,
        "num_view_layers": 2,
        "num_query_layers": 2,
        "num_fusion_layers": 4,
        "decoder_kernel": 11,
        "attn_dropout": 0.1,
        "use_proprio": False,
        "proprio_position": False,
        "proprio_orientation": False,
        "proprio_in_heads": False,
        "proprio_film": False,
        "local_channels": 0,
        "head_activation": "relu",
        "lang_film": False,
        "lang_task_contrast": False,
        "heatmap_refine_px": 0,
        "aug_translation_range": 0.125,
        "aug_yaw_range_deg": 45.0,
        "optimizer_lr": 9.6e-4,
        "optimizer_exempt_small": False,
        "scheduler_warmup_steps": 2000,
        "scheduler_decay_steps": 25000,
        "per_task_bounds": False,
        "yaw_scan_px": 0,
        "contrastive_center": False,
        "heatmap_fusion": "sum",
    },
    "small": {
        "img_size": 64,
        "patch_size": 8,
        "im_channels": 16,
        "final_dim": 16,
        "attn_dim": 128,
        "attn_heads": 4,
        "attn_dim_head": 32,
        "num_view_layers": 1,
        "num_query_layers": 1,
        "num_fusion_layers": 2,
        "decoder_kernel": 3,
        "attn_dropout": 0.0,
        "use_proprio": True,
        "proprio_position": True,
        "proprio_orientation": True,
        "proprio_in_heads": True,
        "proprio_film": True,
        "local_channels": 16,
        "head_activation": "leaky_relu",
        "lang_film": True,
        "lang_task_contrast": True,
        "heatmap_refine_px": 2,
        "aug_translation_range": 0.0,
        "aug_yaw_range_deg": 45.0,
        "optimizer_lr": 1e-2,
        "optimizer_exempt_small": True,
        "scheduler_warmup_steps": 20,
        "scheduler_decay_steps": 2000,
        "per_task_bounds": False,
        "yaw_scan_px": 0,
        "contrastive_center": False,
        "heatmap_fusion": "product",
    },
}
# The multi-task recipe of the suite benchmark (benchmarks/bench_suite.py, RESULTS.md "The suite on 2 CPU cores"):
# the small network with each task in its own box, the yaw scan, and a gentler learning rate decayed over 7500 steps
# (the benchmark's 7500 steps at batch 8 on 50 demonstrations per variation; docs/learning.md "50 demonstrations per
# variation at 7500 steps, a second training draw").
PRESETS["suite"] = PRESETS["small"] | {
    # On the five tasks it scored 60/200 against 60 and 62 without it (docs/learning.md "The proprio FiLM on the
    # five tasks"): the suite's failures are small-object grasps and PickPlace's instruction, not the gripper state.
    "proprio_film": False,
    # On the five tasks at 7500 steps it scored 107/200 against 119/200 without it (seed 0, not in pairs), PickPlace's
    # wrong object unchanged at 33 (docs/learning.md "The instruction contrast on the five tasks").
    "lang_task_contrast": False,
    "per_task_bounds": True,
    "yaw_scan_px": 24,
    "optimizer_lr": 3e-3,
    "scheduler_decay_steps": 7500,
}
# The suite recipe with the capacity a GPU makes cheap, for batch 64 over 3000 steps (docs/gpu.md "The gpu preset").
PRESETS["gpu"] = PRESETS["suite"] | {
    "im_channels": 32,
    "final_dim": 32,
    "attn_dim": 256,
    "attn_heads": 8,
    "num_fusion_layers": 4,
    "scheduler_decay_steps": 3000,
}

ACTION_DIM = KEYFRAME_ACTION_DIM
# A 1 m box over robosuite's table (x toward the robot's front, z up; the table top is at z = 0.8 m).
DEFAULT_SCENE_BOUNDS = [-0.4, -0.55, 0.75, 0.6, 0.5, 1.75]


def _is_box(box: list[float]) -> bool:
    """``(x_lo, y_lo, z_lo, x_hi, y_hi, z_hi)`` with every high above its low."""
    return len(box) == 6 and all(hi > lo for lo, hi in zip(box[:3], box[3:], strict=True))


@PreTrainedConfig.register_subclass("sigma")
@dataclass
class SigmaConfig(PreTrainedConfig):
    """Σ-agent policy configuration (see the module docstring for presets and paper-vs-code choices).

    Units: ``scene_bounds`` metres (xmin, ymin, zmin, xmax, ymax, zmax) in the world frame;
    ``aug_translation_range`` metres; ``aug_yaw_range_deg`` degrees; ``gt_heatmap_sigma`` pixels.
    """

    # paper | small | suite | gpu (PRESETS; the module docstring says what each fills).
    preset: str = "paper"

    # ---- architecture (None = from preset)
    img_size: int | None = None
    patch_size: int | None = None
    im_channels: int | None = None
    # Width of a patch token before its Linear to attn_dim (network.NetworkConfig.patch_channels); 0 = im_channels,
    # as in RVT and every preset.
    patch_channels: int = 0
    final_dim: int | None = None
    attn_dim: int | None = None
    attn_heads: int | None = None
    attn_dim_head: int | None = None
    num_view_layers: int | None = None
    num_query_layers: int | None = None
    num_fusion_layers: int | None = None
    decoder_kernel: int | None = None
    attn_dropout: float | None = None
    num_rotation_bins: int = 72
    render_radius_px: float = 1.32
    head_activation: str | None = None  # None = from preset (paper "relu", small "leaky_relu")
    # Instruction FiLM on the image tokens before fusion (network.LanguageFiLM; None = from preset: paper False,
    # small True).
    lang_film: bool | None = None
    # Amplify what tells a task's instructions apart: each training instruction's token states are read as its task's
    # mean plus g times its deviation from it, g giving the deviations the states' own norm (text_encoder.task_contrast;
    # instruction_tasks says the tasks). Stack's two orders, 0.985 apart, become about orthogonal.
    # None = from preset (``small`` on: Stack's order read in the float32 demo's 700 steps, docs/learning.md "Stack's
    # order in 700 steps"); a config saved before the option existed reads it off (SigmaConfig.from_pretrained).
    lang_task_contrast: bool | None = None

    # ---- paper-vs-code choices (module docstring)
    num_queries: int = 1
    query_attention: str = "self"
    # Loss = bc_lambda * BC + (1 - bc_lambda) * contrastive (the paper's 0.5). 0.9 was measured on the five tasks at
    # the suite benchmark's defaults: +1 point over 0.5 (-1 to +3) in two training draws (docs/learning.md).
    bc_lambda: float = 0.5
    # Weight of an episode's first frame in the BC loss, relative to its other frames (1 = all equal). The first
    # frame's target (start pose -> above the object) is where the scene and the instruction decide the position;
    # later keyframes follow the hand. The batch's weights are scaled to mean 1, so the loss keeps its size.
    first_keyframe_weight: float = 1.0
    mask_same_instruction: bool = True
    mask_same_task: bool = False
    use_proprio: bool | None = None  # None = from preset (paper False, small True)
    # With use_proprio: add the grip site's position in the scene box ([-1, 1] per axis, after augmentation) to the
    # proprio token. None = from preset (paper False, small True).
    proprio_position: bool | None = None
    # With use_proprio: add the grip site's orientation (first two columns of its rotation matrix, rotated by the
    # augmentation) to the proprio token. None = from preset.
    proprio_orientation: bool | None = None
    # With use_proprio: the proprio vector also enters the rotation/gripper/collision MLP. None = from preset.
    proprio_in_heads: bool | None = None
    # With use_proprio: the proprio vector also scales and shifts every image token entering fusion
    # (network.ProprioFiLM), so the heatmap reads the gripper state directly. None = from preset.
    proprio_film: bool | None = None
    # Channels of the heads' local encoder (network.LocalEncoder: full-resolution dilated convolutions pooled at
    # the keyframe position); 0 = off. None = from preset.
    local_channels: int | None = None
    # The local features also enter the translation decoder beside its 1x1-convolution skip (network_config.py).
    # Off in every preset: NutAssembly alone gained with it, the five-task suite did not (docs/learning.md "Local
    # features in the translation decoder" and "... on the five tasks").
    local_in_decoder: bool = False
    # Side views tilted down by this many degrees (sigma_policy/views.py), so that they see over a container's rim,
    # e.g. PickPlace's bins, whose walls hide the bread and the can from horizontal views (docs/learning.md). 0 =
    # RVT's horizontal side views (every preset: 45° and 30° both fitted and scored worse on PickPlace).
    side_tilt_deg: float = 0.0
    # The virtual views rendered (sigma_policy/views.py "Fewer views"): RVT's five (every preset), or a subset with
    # 'top', one of 'front'/'back' and one of 'left'/'right'. RVT-2's three trained 1.6x faster on 2 CPU cores but
    # lost Stack's order on the demo's data (docs/learning.md "Three virtual views").
    virtual_views: list[str] = field(default_factory=lambda: list(VIEW_NAMES))
    # Rotation-equivariant yaw scores (sigma_policy/yaw_scan.py): side (pixels) of the top-view crop around the
    # keyframe position that is turned to every yaw bin and scored by one CNN (0 = off); its channels; the training
    # jitter (pixels, uniform per axis) of the crop's centre about the target's projection, standing in for the
    # translation error the crop sits with at inference.
    yaw_scan_px: int | None = None  # None = from preset (paper and small 0, suite 24)
    yaw_scan_channels: int = 16
    yaw_scan_jitter_px: float = 1.0
    logit_scale_init: float = math.log(1 / 0.07)
    logit_scale_max: float | None = None
    projection_activation: bool = True
    place_with_mean_at_eval: bool = False
    # Test-time yaw ensemble (inference only; sigma_policy/test_time.py): besides the observation as it is, the
    # policy predicts on it turned by each of these angles (degrees, multiples of the rotation bins' width) about
    # the box's vertical centre line and the passes vote, the winner's neighbours within ``tta_radius_m`` metres
    # averaged. [] = off (every preset); each angle adds one inference pass.
    tta_yaw_deg: list[float] = field(default_factory=list)
    tta_radius_m: float = 0.02
    # How the views' heatmaps vote for the 3D point (inference only; sigma_policy/heatmap.py, docs/method.md §14.6):
    # "sum" of their probabilities (RVT) or "product" (every view must agree). None = from preset (paper "sum", small
    # "product": +2 points over 400 five-task pairs, 14 episodes won and 5 lost, docs/learning.md).
    heatmap_fusion: str | None = None
    # Instruction-contrastive decoding (inference only; sigma_policy/instruction_contrast.py): each view's heatmap
    # under the instruction is divided by the ``instruction_contrast``-th power of the mean heatmap over every
    # instruction of its task (``instruction_tasks``), so a place all of them point at loses to the place only this
    # one points at; the heads are then run at the contrasted point. In [0, 1); 0 = off (every preset); each other
    # instruction of the task adds one network run, and one more runs the heads.
    instruction_contrast: float = 0.0
    # Instruction negatives (training only; sigma_policy/instruction_contrast.py): each first frame of an episode
    # whose task has other instructions (``instruction_tasks``) is run once more under one of them, drawn at random,
    # and ``instruction_negative_weight`` x the unlikelihood of its own keyframe there (-log(1 - q), q the heatmap
    # mass within ``instruction_negative_sigma_px`` of the target) joins its BC loss. 0 = off. Costs one network run
    # on the batch's first frames.
    instruction_negative_weight: float = 0.0
    instruction_negative_sigma_px: float = 3.0
    # Sub-voxel refinement of the translation at inference: centroid of the score profiles within this many
    # voxels of the argmax (sigma_policy/heatmap.py); 0 = the argmax voxel centre (RVT). None = from preset
    # (paper 0, small 2).
    heatmap_refine_px: int | None = None
    detach_heatmap_for_features: bool = True

    # ---- contrastive IL
    use_contrastive: bool = True
    # Subtract the goal term's features' batch mean before the L2 normalisation (sigma_policy/contrastive.py; not
    # in the paper; docs/method.md §13.2). None = from preset (every preset False).
    contrastive_center: bool | None = None

    # ---- inputs
    cameras: list[str] = field(default_factory=list)
    depth_unit: str = (
        "mm"  # LeRobotDataset's default depth_output_unit; "m" with --dataset.depth_output_unit=m
    )
    # None = the union of the task boxes in the training dataset's meta/sigma.json ("bounds"), else
    # DEFAULT_SCENE_BOUNDS; resolved when the policy is built for training and saved with the checkpoint.
    scene_bounds: list[float] | None = None
    # Each instruction uses its own task's box (``instruction_bounds``) instead of one box for every task: a
    # multi-task policy then gives Stack's cubes the pixels of a 36 cm box while PickPlace keeps its 1 m box.
    # ``scene_bounds`` (the union) stays the box of an instruction the policy was not trained on.
    per_task_bounds: bool | None = None  # None = from preset (paper and small False, suite True)
    # instruction -> (xmin, ymin, zmin, xmax, ymax, zmax); filled from the training dataset's meta/sigma.json
    # (each episode's instruction and its task's recorded box) when ``per_task_bounds`` and left empty.
    instruction_bounds: dict[str, list[float]] = field(default_factory=dict)
    # instruction -> task name; filled from the training dataset's meta/sigma.json when empty (``mask_same_task`` and
    # ``instruction_contrast`` read it). An instruction missing here is a task of its own.
    instruction_tasks: dict[str, str] = field(default_factory=dict)
    text_encoder: str = "minilm"
    text_encoder_path: str | None = None

    # ---- augmentation and labels (training only)
    aug_translation_range: float | None = None  # None = from preset (paper 0.125, small 0)
    # What the translation range is counted in: "m" (metres, every axis alike) or "box" (a fraction of the sample's
    # box extent per axis, RVT's convention: 0.125 is +-12.5 cm on a 1 m box and +-4.5 cm on Lift's 36 cm one).
    aug_translation_unit: str = "m"
    # The translation range grows linearly from 0 to its full value over this many training steps (0 = full from
    # the first step): a short run fits the scenes as they are first, then sees them moved (docs/method.md §9).
    aug_translation_ramp_steps: int = 0
    aug_yaw_range_deg: float | None = None  # None = from preset (paper 45, small 0)
    image_noise: float = 0.1
    gt_heatmap_sigma: float = 1.5

    # ---- optimisation (None = from preset); LAMB + linear warm-up + cosine decay to lr / 100
    optimizer_lr: float | None = None
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    optimizer_eps: float = 1e-6
    optimizer_weight_decay: float = 1e-6
    optimizer_grad_clip_norm: float = 0.0  # Σ does not clip; LeRobot skips clipping when <= 0
    # Biases, norms, logit scale and query tokens skip LAMB's trust ratio and weight decay (None = from preset).
    optimizer_exempt_small: bool | None = None
    scheduler_warmup_steps: int | None = None
    scheduler_decay_steps: int | None = None
    # A moving average of the weights, updated after every optimiser step: w_avg <- d w_avg + (1 - d) w, with
    # d = ema_decay (0 = off; 0.998 averages about the last 500 steps). Outside training the policy acts with the
    # average unless act_with_ema is false (docs/method.md §10.1, sigma_policy/weight_average.py).
    ema_decay: float = 0.0
    act_with_ema: bool = True

    # ---- precision
    use_bf16_autocast: bool = True  # bf16 autocast of the network on CUDA devices that support it
    # bf16 autocast of the network on CPUs with native bf16 arithmetic (AVX512-BF16 or AMX; oneDNN says which).
    # The point renderer, losses and the optimiser stay float32. About 1.3x faster training steps on the 2-core
    # AMD EPYC (docs/learning.md "Training speed").
    use_cpu_bf16_autocast: bool = False

    # ---- LeRobot plumbing
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.IDENTITY,
        }
    )
    # Observation keys the normaliser may touch; camera calibration and depth are never normalised.
    normalize_observation_keys: list[str] = field(default_factory=lambda: ["observation.state"])
    push_to_hub: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.preset not in PRESETS:
            raise ValueError(f"policy.preset must be one of {sorted(PRESETS)}, got {self.preset!r}")
        for name, value in PRESETS[self.preset].items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        if self.scene_bounds is not None and not _is_box(self.scene_bounds):
            raise ValueError(
                f"policy.scene_bounds must be (xmin, ymin, zmin, xmax, ymax, zmax), got {self.scene_bounds}"
            )
        if self.depth_unit not in ("m", "mm"):
            raise ValueError(f"policy.depth_unit must be 'm' or 'mm', got {self.depth_unit!r}")
        if self.aug_translation_unit not in ("m", "box"):
            raise ValueError(
                f"policy.aug_translation_unit must be 'm' or 'box', got {self.aug_translation_unit!r}"
            )
        if self.aug_translation_ramp_steps < 0:
            raise ValueError(
                f"policy.aug_translation_ramp_steps must be >= 0, got {self.aug_translation_ramp_steps}"
            )
        if not 0.0 < self.bc_lambda <= 1.0:
            raise ValueError(f"policy.bc_lambda must be in (0, 1], got {self.bc_lambda}")
        if not self.first_keyframe_weight > 0.0:
            raise ValueError(f"policy.first_keyframe_weight must be > 0, got {self.first_keyframe_weight}")
        for instruction, box in self.instruction_bounds.items():
            if not _is_box(box):
                raise ValueError(f"policy.instruction_bounds[{instruction!r}] must be a box of 6, got {box}")
        self.tta_yaw_deg = check_yaw_angles(self.tta_yaw_deg, self.num_rotation_bins)
        self.heatmap_fusion = check_heatmap_fusion(self.heatmap_fusion)
        try:
            view_indices(self.virtual_views)
        except ValueError as e:
            raise ValueError(f"policy.{e}") from None
        self.instruction_contrast = check_contrast_weight(self.instruction_contrast)
        if not self.instruction_negative_weight >= 0.0:
            raise ValueError(
                f"policy.instruction_negative_weight must be >= 0, got {self.instruction_negative_weight}"
            )
        if not self.instruction_negative_sigma_px > 0.0:
            raise ValueError(
                f"policy.instruction_negative_sigma_px must be > 0, got {self.instruction_negative_sigma_px}"
            )
        self.ema_decay = check_ema_decay(self.ema_decay)
        if not self.tta_radius_m > 0.0:
            raise ValueError(f"policy.tta_radius_m must be > 0, got {self.tta_radius_m}")
        self.network_config()  # validates the architecture numbers early

    # ------------------------------------------------------------------ LeRobot hooks
    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: str | Path, **kwargs: Any) -> SigmaConfig:
        """LeRobot's reader of a saved ``config.json``, after taking out the options sigma has retired
        (sigma_policy/compat.py): a checkpoint saved before an option was removed loads if it left that option
        off, and is refused, naming the file and the option, if it did not. A field saved before it existed takes
        its default, or its preset's value (``heatmap_fusion`` of a config saved before 2026-12-06), except an
        option that adds no weights, which reads as off (``lang_task_contrast``; compat.fill_added_off). Every
        reader of a checkpoint's options goes through here; an invalid value is a ValueError naming the file."""
        config_file = Path(pretrained_name_or_path) / CONFIG_NAME
        if not config_file.is_file():  # a hub id, or no config: LeRobot's own reader says what is wrong
            return super().from_pretrained(pretrained_name_or_path, **kwargs)
        values = json.loads(config_file.read_text())
        kept = fill_added_off(drop_retired(values, str(config_file)))
        try:
            if kept == values:
                return super().from_pretrained(pretrained_name_or_path, **kwargs)
            with tempfile.TemporaryDirectory() as tmp:
                (Path(tmp) / CONFIG_NAME).write_text(json.dumps(kept))
                return super().from_pretrained(tmp, **kwargs)
        except draccus.utils.ParsingError as e:  # names the class only; the cause says which field
            raise ValueError(f"{config_file}: {e.__cause__ or e}") from e

    @property
    def drop_n_last_frames(self) -> int:
        """The last keyframe of an episode is a goal only, never a training sample."""
        return 1

    @property
    def observation_delta_indices(self) -> list[int]:
        """Frame i and its goal, the next keyframe i + 1 (only i is used without the contrastive loss)."""
        return [0, 1] if self.use_contrastive else [0]

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> LambConfig:
        return LambConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> CosineDecayWithWarmupSchedulerConfig:
        return CosineDecayWithWarmupSchedulerConfig(
            num_warmup_steps=self.scheduler_warmup_steps,
            num_decay_steps=self.scheduler_decay_steps,
            peak_lr=self.optimizer_lr,
            decay_lr=self.optimizer_lr / 100,
        )

    def validate_features(self) -> None:
        """Check that every used camera has RGB, depth, intrinsics and extrinsics, and that the action is 9-D."""
        cams = self.camera_names()
        if not cams:
            raise ValueError(
                "sigma needs at least one camera with 'observation.images.<cam>', "
                "'observation.images.<cam>_depth', 'observation.camera.<cam>.intrinsics' and "
                f"'.extrinsics' among the input features; got {sorted(self.input_features or {})}"
            )
        feats = self.input_features or {}
        for cam in cams:
            for key in self.camera_keys(cam).values():
                if key not in feats:
                    raise ValueError(f"camera '{cam}': input feature '{key}' is missing from the dataset")
        if self.action_feature is not None and tuple(self.action_feature.shape) != (ACTION_DIM,):
            raise ValueError(
                f"sigma predicts a 9-D keyframe action, but feature 'action' has shape {self.action_feature.shape}"
            )

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def camera_keys(cam: str) -> dict[str, str]:
        return {
            "rgb": rgb_key(cam),
            "depth": depth_key(cam),
            "intrinsics": intrinsics_key(cam),
            "extrinsics": extrinsics_key(cam),
        }

    def camera_names(self) -> list[str]:
        """The cameras the policy fuses: ``cameras`` if set, else every RGB camera with a depth feature."""
        if self.cameras:
            return list(self.cameras)
        feats = self.input_features or {}
        return sorted(
            key.removeprefix(IMAGE_PREFIX)
            for key, ft in feats.items()
            if ft.type is FeatureType.VISUAL
            and key.startswith(IMAGE_PREFIX)
            and not key.endswith(DEPTH_SUFFIX)
            and f"{key}{DEPTH_SUFFIX}" in feats
        )

    def fill_from_dataset(self, dataset_root: str | Path | None = None) -> list[float]:
        """Fill the fields that come from the dataset when they are unset: ``scene_bounds`` (the union of the task
        boxes a sigma dataset records in ``meta/sigma.json``, ``"bounds": {task: box}``, else
        :data:`DEFAULT_SCENE_BOUNDS`), with ``per_task_bounds`` ``instruction_bounds``, and ``instruction_tasks``.
        Returns ``scene_bounds``."""
        if self.per_task_bounds and not self.instruction_bounds and dataset_root is not None:
            self.instruction_bounds = recorded_instruction_bounds(dataset_root)
        if not self.instruction_tasks and dataset_root is not None:
            self.instruction_tasks = recorded_instruction_tasks(dataset_root)
        if self.scene_bounds is None:
            boxes = recorded_bounds(dataset_root) if dataset_root is not None else []
            if boxes:
                lo = [min(b[i] for b in boxes) for i in range(3)]
                hi = [max(b[i] for b in boxes) for i in range(3, 6)]
                self.scene_bounds = [float(v) for v in lo + hi]
            else:
                self.scene_bounds = list(DEFAULT_SCENE_BOUNDS)
        if self.yaw_scan_px:
            self._check_square_boxes()
        return self.scene_bounds

    def task_boxes(self) -> dict[str, list[float]]:
        """The per-instruction boxes the policy renders with: ``instruction_bounds`` with ``per_task_bounds`` (when
        any are recorded), else none, and every sample is rendered in ``scene_bounds``."""
        return self.instruction_bounds if self.per_task_bounds and self.instruction_bounds else {}

    def _check_square_boxes(self) -> None:
        """The yaw scan turns a top-view crop in pixels, which is a turn in the world only where a pixel is as wide
        in x as in y (docs/method.md §7.1): every box the policy renders with must be square in x-y."""
        boxes = {f"instruction_bounds[{k!r}]": b for k, b in self.task_boxes().items()}
        boxes = boxes or {"scene_bounds": self.scene_bounds}
        for name, box in boxes.items():
            dx, dy = box[3] - box[0], box[4] - box[1]
            if abs(dx - dy) > 1e-6 * max(dx, dy):
                raise ValueError(
                    f"yaw_scan_px needs boxes as wide in x as in y (docs/method.md §7.1): {name} = {list(box)} "
                    f"is {dx:.3f} m x {dy:.3f} m"
                )

    def network_config(self) -> NetworkConfig:
        """Architecture numbers for ``SigmaNetwork`` (language dimensions come from the text encoder)."""
        names = {f.name for f in fields(NetworkConfig)}
        values = {k: getattr(self, k) for k in names if hasattr(self, k) and getattr(self, k) is not None}
        values["proprio_dim"] = 3 + 3 * bool(self.proprio_position) + 6 * bool(self.proprio_orientation)
        values["head_pool_sigma"] = self.gt_heatmap_sigma
        values["views"] = view_indices(self.virtual_views)
        return NetworkConfig(**values)
