"""``SigmaPolicy``: the Σ-agent keyframe policy as a LeRobot ``PreTrainedPolicy`` (``--policy.type=sigma``).

Per sample and frame (current frame i, and in training its goal, keyframe i+1, from
``observation_delta_indices=[0, 1]``):

1. Each camera's metric depth + intrinsics + camera-to-world extrinsics -> world points, coloured by its RGB;
   all cameras are concatenated into one cloud (B, N, 3) (``observation.py``, which reads every batch field).
2. Training only: SE(3) augmentation (±``aug_translation_range``, in metres or box extents, ±``aug_yaw_range_deg``
   yaw about the target position; the goal gets its own draw, pivoting on the goal frame's end-effector position;
   ``augmentation.py``).
3. Crop to the sample's box (``scene_bounds``, or its task's with ``per_task_bounds``), map to the canonical cube
   [-1, 1]^3 (``pointcloud.py``), render the orthographic virtual views (B, V, 10, img_size, img_size; V = 5, or
   fewer with ``virtual_views``; ``renderer.py``); training adds the uniform render noise of docs/method.md §4.3
   on channels 0-6.
4. The network (``network.py``) with frozen, cached text-encoder tokens of ``task``.

Losses (docs/method.md §6.1, §7; ``behaviour_cloning.py``): translation = soft-target cross-entropy of each view's
heatmap against a Gaussian (sigma ``gt_heatmap_sigma`` px) at the projected target; 3 x ``num_rotation_bins``
Euler-bin CE; gripper CE; collision CE; BC = their sum. Total = ``bc_lambda`` · BC + (1 − ``bc_lambda``) ·
contrastive, or BC alone with ``use_contrastive=False``.

Action (9,): ``[x, y, z, qx, qy, qz, qw, gripper_open, ignore_collision]`` in world metres, quaternion xyzw with
w >= 0, the two flags in {0, 1}. ``predict`` also returns the rendered views, per-view heatmaps and the 3D point
for visualisation; ``select_action`` keeps the latest in ``last_prediction``.
"""

from __future__ import annotations

import logging
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_STATE
from torch import Tensor

from sigma_data.contract import STATE_QUAT
from sigma_policy import lerobot_patches
from sigma_policy.augmentation import add_render_noise, se3_augment
from sigma_policy.behaviour_cloning import bc_losses
from sigma_policy.compat import match_saved_modules
from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.contrastive import contrastive_losses, instruction_ids
from sigma_policy.ensemble import check_members, mean_probability_logits
from sigma_policy.heatmap import gaussian_heatmaps, heads_at_point, heatmap_to_cube_point
from sigma_policy.instruction_contrast import contrast_instructions, instruction_negatives
from sigma_policy.network import NetworkOutput, SigmaNetwork
from sigma_policy.observation import Cloud, batch_tasks, camera_cloud, first_frames, proprio_input, take
from sigma_policy.pointcloud import cloud_box, crop_to_cube, cube_to_world, world_to_cube
from sigma_policy.renderer import VirtualViewRenderer
from sigma_policy.rotation import bins_to_quat
from sigma_policy.test_time import (
    EnsemblePass,
    consensus,
    roll_yaw_bins,
    transform_points,
    yaw_about_box_centre,
)
from sigma_policy.text_encoder import make_text_encoder, task_contrast
from sigma_policy.views import view_indices
from sigma_policy.weight_average import WeightAverage


def cpu_has_native_bf16() -> bool:
    """Whether oneDNN runs bf16 natively on this CPU (AVX512-BF16 or AMX); elsewhere bf16 is emulated and slower."""
    return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())


@dataclass
class SigmaPrediction:
    """One inference step, for acting and for visualisation (all tensors on the policy device)."""

    action: Tensor  # (B, 9) world-frame next-keyframe action
    views: Tensor  # (B, V, 10, H, W) rendered virtual views (channels: xyz, rgb, depth, view id, row, col)
    heatmaps: Tensor  # (B, V, H, W) per-view translation probabilities (each view sums to 1)
    point_cube: Tensor  # (B, 3) predicted translation in cube coordinates
    point_world: Tensor  # (B, 3) predicted translation in world metres
    rotation_bins: Tensor  # (B, 3) argmax Euler bins
    bounds: Tensor  # (B, 6) world box that was mapped to the cube
    rotation_probs: Tensor  # (B, 3, num_rotation_bins) softmax per Euler axis
    gripper_probs: Tensor  # (B, 2) [closed, open]
    collision_probs: Tensor  # (B, 2) [avoid, ignore]
    cloud_points: Tensor  # (B, N, 3) fused world-frame input cloud, metres (NaN where depth was invalid)
    cloud_colors: Tensor  # (B, N, 3) its RGB in [0, 1]


class SigmaPolicy(PreTrainedPolicy):
    """Σ-agent: RVT-style multi-view transformer with an MVQ-Former and contrastive IL (see module docstring)."""

    config_class = SigmaConfig
    name = "sigma"

    def __init__(
        self, config: SigmaConfig, dataset_stats: dict | None = None, dataset_meta: Any = None, **kwargs
    ):
        super().__init__(config)
        del dataset_stats, kwargs  # no statistics needed: the scene box is the normalisation
        lerobot_patches.install()  # faster multi-frame reads of the datasets this policy trains on (idempotent)
        config.validate_features()
        config.fill_from_dataset(getattr(dataset_meta, "root", None))
        if (
            dataset_meta is not None
            and config.use_contrastive
            and config.mask_same_task
            and not config.instruction_tasks
        ):
            logging.getLogger(__name__).warning(
                "mask_same_task: no instruction -> task map (policy.instruction_tasks, or a dataset whose "
                "meta/sigma.json records each episode's task); only same-instruction negatives are masked"
            )
        if dataset_meta is not None and config.lang_task_contrast and not config.instruction_tasks:
            logging.getLogger(__name__).warning(
                "lang_task_contrast: no instruction -> task map (policy.instruction_tasks, or a dataset whose "
                "meta/sigma.json records each episode's task); every instruction is read as it is"
            )
        if dataset_meta is not None and config.instruction_negative_weight and not config.instruction_tasks:
            raise ValueError(
                "instruction_negative_weight: no instruction -> task map (policy.instruction_tasks, or a dataset "
                "whose meta/sigma.json records each episode's task), so no sample has another instruction to ask"
            )
        self.config: SigmaConfig = config
        self.cameras = config.camera_names()
        self._depth_checked = False
        self._warned_instructions: set[str] = set()
        # Which other instruction an instruction negative asks: a stream of its own, seeded by the run's seed, so
        # that turning the option on leaves every other draw of training (augmentation, dropout) as it was.
        self._negative_draws = torch.Generator().manual_seed(torch.initial_seed())
        # Frozen and cached per instruction; kept outside the module tree so it is neither saved nor trained.
        self.__dict__["text_encoder"] = make_text_encoder(config.text_encoder, config.text_encoder_path)
        self._lang_cache: dict[str, tuple[Tensor, Tensor]] = {}
        # lang_task_contrast's token states per training instruction, computed on first use
        self._task_contrast: dict[str, Tensor] | None = None
        self._build_network()
        self.renderer = VirtualViewRenderer(
            img_size=config.img_size,
            radius_px=config.render_radius_px,
            side_tilt_deg=config.side_tilt_deg,
            views=view_indices(config.virtual_views),
        )
        self.register_buffer(
            "scene_bounds", torch.tensor(config.scene_bounds, dtype=torch.float32), persistent=False
        )
        if config.aug_translation_ramp_steps:
            # Training steps taken, for the translation ramp; saved with the weights so that a resumed run goes on
            # where it stopped (only registered with a ramp, so other checkpoints keep their keys).
            self.register_buffer("aug_steps_taken", torch.zeros((), dtype=torch.long))
        self.last_prediction: SigmaPrediction | None = None
        # Further trained policies this one acts with (sigma_policy/ensemble.py); not part of this one's weights.
        self.__dict__["ensemble_members"] = []

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: Any, *, config: SigmaConfig | None = None, **kwargs):
        """LeRobot's loader, with the config read by :meth:`SigmaConfig.from_pretrained` (which takes out the
        options sigma has retired, sigma_policy/compat.py) when none is given."""
        if config is None and Path(pretrained_name_or_path).is_dir():
            config = SigmaConfig.from_pretrained(pretrained_name_or_path)
        return super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)

    @classmethod
    def _load_as_safetensor(cls, model, model_file: str, map_location: str, strict: bool):
        """LeRobot's loader, after rebuilding the network without the modules the file was saved before
        (sigma_policy/compat.py, "Added modules")."""
        match_saved_modules(model.config, model_file)
        if model.network.cfg != model.config.network_config():
            model._build_network()
        return super()._load_as_safetensor(model, model_file, map_location, strict)

    def _build_network(self) -> None:
        """The network for ``self.config``, and with ``ema_decay`` its moving average (``weight_average``)."""
        self.network = SigmaNetwork(
            self.config.network_config(),
            self.text_encoder.token_dim,
            self.text_encoder.sentence_dim,
            self.text_encoder.max_length,
        )
        self.weight_average = (
            WeightAverage(self.network, self.config.ema_decay) if self.config.ema_decay else None
        )

    # ------------------------------------------------------------------ LeRobot API
    def get_optim_params(self):
        """All network parameters; with ``optimizer_exempt_small`` two LAMB groups: matrices and convolution
        kernels with the trust ratio, and without it (no weight decay either) the tensors a trust ratio keeps near
        their small initial norm: biases, norm gains/offsets, the logit scale and the zero-initialised query
        tokens (``sigma_policy/lamb.py``)."""
        # Not the weight average, whose copy of the network has no gradients.
        trained = [(name, p) for name, p in self.named_parameters() if p.requires_grad]
        if not self.config.optimizer_exempt_small:
            return [p for _, p in trained]
        exempt, rest = [], []
        for name, p in trained:
            (exempt if p.ndim <= 1 or name.endswith("query_tokens") else rest).append(p)
        return [{"params": rest}, {"params": exempt, "trust_ratio": False, "weight_decay": 0.0}]

    def reset(self) -> None:
        self.last_prediction = None

    def update(self) -> None:
        """After every optimiser step (LeRobot's training loop calls it): move the weight average, if any."""
        if self.weight_average is not None:
            self.weight_average.update(self.network)

    def acting_network(self) -> SigmaNetwork:
        """The network a pass runs: the weight average outside training (unless ``act_with_ema`` is off),
        else the trained one."""
        if self.weight_average is not None and self.config.act_with_ema and not self.training:
            return self.weight_average.network
        return self.network

    def add_ensemble_members(self, members: list[SigmaPolicy], names: list[str]) -> None:
        """Act from now on with ``members`` (policies trained on the same data, in eval mode on this policy's
        device) as one ensemble (sigma_policy/ensemble.py); ``names`` name them in errors (their checkpoints)."""
        check_members(self.config, [m.config for m in members], names)
        self.__dict__["ensemble_members"] = list(members)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Any], **kwargs) -> Tensor:
        """(B, 9) next-keyframe action for a batch of single observations (no time dimension)."""
        self.last_prediction = self.predict(batch)
        return self.last_prediction.action

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Any], **kwargs) -> Tensor:
        return self.predict(batch).action.unsqueeze(1)

    def forward(self, batch: dict[str, Any], reduction: str = "mean") -> tuple[Tensor, dict[str, float]]:
        """Training loss on a batch whose ``observation.*`` tensors carry a time axis [current, goal].

        ``reduction="none"`` returns per-sample losses (B,): each sample's BC loss plus the (batch-level)
        contrastive loss, weighted by ``bc_lambda``.
        """
        cfg = self.config
        action = batch[ACTION].float()
        if action.ndim != 2 or action.shape[1] != 9:
            raise ValueError(f"batch['action'] must be (B, 9), got {tuple(action.shape)}")
        tasks = batch_tasks(batch, action.shape[0])
        bounds = self._bounds(tasks)

        if cfg.aug_translation_ramp_steps and torch.is_grad_enabled():
            self.aug_steps_taken += 1
        shift = self._translation_range(bounds)
        views, pos, quat, transforms = self._augmented_views(
            batch, 0, action[:, :3], action[:, 3:7], bounds, shift
        )
        goal_views = None
        if cfg.use_contrastive:
            state = take(batch, OBS_STATE, t=1, item_ndim=1).float()
            goal_views, *_ = self._augmented_views(
                batch, 1, state[:, :3], state[:, STATE_QUAT], bounds, shift
            )

        target_uv = self.renderer.project(world_to_cube(pos[:, None], bounds))[:, 0]  # (B, V, 2)
        target_hm = gaussian_heatmaps(target_uv, cfg.img_size, sigma=cfg.gt_heatmap_sigma)
        scan_uv = None
        if cfg.yaw_scan_px:
            # The scan's crop sits where inference will put it, give or take inference's translation error.
            scan_uv = target_uv + (torch.rand_like(target_uv) * 2 - 1) * cfg.yaw_scan_jitter_px
        out = self._run_network(
            views,
            tasks,
            batch,
            bounds,
            goal_views=goal_views,
            transforms=transforms,
            head_heatmap=target_hm,
            head_uv=scan_uv,
        )

        bc_terms = bc_losses(
            out.trans, target_hm, out.rot_logits, out.grip_logits, out.collision_logits, action, quat
        )
        info = bc_terms.info()
        per_sample = bc = bc_terms.total * self._frame_weights(batch, bc_terms.total)
        if cfg.instruction_negative_weight:
            negative = self._instruction_negatives(views, tasks, batch, bounds, transforms, target_uv)
            info["instruction_negative_loss"] = negative.sum().item() / max(int((negative > 0).sum()), 1)
            per_sample = bc = bc + cfg.instruction_negative_weight * negative
        if cfg.use_contrastive:
            group = self._negative_groups(tasks, bc.device)
            cl = contrastive_losses(
                out.state_feat,
                out.lang_feat,
                out.fused_feat,
                out.goal_feat,
                out.logit_scale,
                instruction_group=group,
                logit_scale_max=cfg.logit_scale_max,
                center=cfg.contrastive_center,
            )
            per_sample = cfg.bc_lambda * bc + (1 - cfg.bc_lambda) * cl.total
            info |= {
                "contrastive_sl_loss": cl.state_language.item(),
                "contrastive_goal_loss": cl.goal.item(),
                "contrastive_loss": cl.total.item(),
                "logit_scale": out.logit_scale.item(),
            }
        if reduction == "none":
            return per_sample, info
        if reduction != "mean":
            raise ValueError(f"reduction must be 'mean' or 'none', got {reduction!r}")
        return per_sample.mean(), info

    # ------------------------------------------------------------------ inference
    @torch.no_grad()
    def predict(self, batch: dict[str, Any]) -> SigmaPrediction:
        """Deterministic prediction (no augmentation, no render noise) with everything needed to visualise it;
        with ``tta_yaw_deg`` the turned passes vote on the action (sigma_policy/test_time.py), and the views and
        heatmaps are the unturned pass's."""
        cfg = self.config
        cloud, tasks, bounds = self._inference_scene(batch)
        views, out, best = self._predict_pass(cloud, tasks, bounds, batch)
        if cfg.tta_yaw_deg:
            turned = [self._predict_pass(cloud, tasks, bounds, batch, d)[2] for d in cfg.tta_yaw_deg]
            best = consensus([best, *turned], cfg.tta_radius_m)
        point_world = best.point
        rot_bins = best.rotation_probs.argmax(-1)
        quat = bins_to_quat(rot_bins, cfg.num_rotation_bins)
        grip = best.gripper_probs.argmax(-1, keepdim=True).float()
        coll = best.collision_probs.argmax(-1, keepdim=True).float()
        action = torch.cat([point_world, quat.to(point_world.dtype), grip, coll], dim=-1)
        trans = out.trans.float()
        return SigmaPrediction(
            action=action,
            views=views,
            heatmaps=torch.softmax(trans.flatten(2), -1).reshape(trans.shape),
            point_cube=world_to_cube(point_world, bounds),
            point_world=point_world,
            rotation_bins=rot_bins,
            bounds=bounds,
            rotation_probs=best.rotation_probs,
            gripper_probs=best.gripper_probs,
            collision_probs=best.collision_probs,
            cloud_points=cloud.points,
            cloud_colors=cloud.colors,
        )

    def _predict_pass(
        self, cloud: Cloud, tasks: list[str], bounds: Tensor, batch: dict[str, Any], degrees: float = 0.0
    ) -> tuple[Tensor, NetworkOutput, EnsemblePass]:
        """One inference pass over ``cloud`` turned by ``degrees`` about the box's vertical centre line (and the
        gripper's pose with it; sigma_policy/test_time.py): the rendered views, the network's output and the
        prediction turned back into the observation's frame."""
        cfg = self.config
        T = yaw_about_box_centre(bounds, degrees) if degrees else None
        points = transform_points(T, cloud.points) if T is not None else cloud.points
        views = self._render(points, cloud.colors, bounds)
        out = self._run_network(views, tasks, batch, bounds, transforms=T)
        if self.ensemble_members:
            out = self._ensemble_output(views, tasks, batch, bounds, T, out)
        if cfg.instruction_contrast:

            def run(asked: list[str], **heads: Tensor) -> NetworkOutput:
                return self._run_network(views, asked, batch, bounds, transforms=T, **heads)

            out = contrast_instructions(
                run,
                out,
                tasks,
                cfg.instruction_tasks,
                cfg.instruction_contrast,
                cfg.gt_heatmap_sigma,
                cfg.side_tilt_deg,
                cfg.heatmap_fusion,
                self.renderer.views,
            )
        point_cube = heatmap_to_cube_point(
            out.trans.float(),
            cfg.img_size,
            refine_px=cfg.heatmap_refine_px,
            side_tilt_deg=cfg.side_tilt_deg,
            fusion=cfg.heatmap_fusion,
            views=self.renderer.views,
        )
        point = cube_to_world(point_cube, bounds)
        rotation_probs = torch.softmax(out.rot_logits.float(), -1)
        if T is not None:
            point = transform_points(T, point, inverse=True)
            rotation_probs = roll_yaw_bins(rotation_probs, degrees)
        prediction = EnsemblePass(
            point=point,
            rotation_probs=rotation_probs,
            gripper_probs=torch.softmax(out.grip_logits.float(), -1),
            collision_probs=torch.softmax(out.collision_logits.float(), -1),
        )
        return views, out, prediction

    def _ensemble_output(
        self,
        views: Tensor,
        tasks: list[str],
        batch: dict[str, Any],
        bounds: Tensor,
        transforms: Tensor | None,
        out: NetworkOutput,
    ) -> NetworkOutput:
        """The ensemble's output for one pass (sigma_policy/ensemble.py): this policy's ``out`` and every member's
        heatmaps averaged in probability, then every policy's heads run at the common point and averaged."""
        cfg = self.config
        policies = [self, *self.ensemble_members]
        outs = [out] + [
            m._run_network(views, tasks, batch, bounds, transforms=transforms) for m in policies[1:]
        ]
        trans = mean_probability_logits([o.trans for o in outs], event_dims=2)  # per view
        heads = heads_at_point(
            trans, cfg.side_tilt_deg, cfg.gt_heatmap_sigma, cfg.heatmap_fusion, self.renderer.views
        )
        pooled = [
            p._run_network(views, tasks, batch, bounds, transforms=transforms, **heads) for p in policies
        ]
        result = pooled[0]
        result.trans = trans
        result.rot_logits = mean_probability_logits([o.rot_logits for o in pooled])
        result.grip_logits = mean_probability_logits([o.grip_logits for o in pooled])
        result.collision_logits = mean_probability_logits([o.collision_logits for o in pooled])
        return result

    @torch.no_grad()
    def input_cloud(self, batch: dict[str, Any]) -> tuple[Tensor, Tensor, Tensor]:
        """What :meth:`predict` renders, without the network: the fused camera cloud's points (B, N, 3) and
        colours (B, N, 3), and each sample's box (B, 6)."""
        cloud, _, bounds = self._inference_scene(batch)
        return cloud.points, cloud.colors, bounds

    # ------------------------------------------------------------------ internals
    def _inference_scene(self, batch: dict[str, Any]) -> tuple[Cloud, list[str], Tensor]:
        """The first frame's cloud, the instructions and the boxes inference renders them in."""
        cloud = self._cloud(batch, t=0)
        tasks = batch_tasks(batch, cloud.points.shape[0])
        bounds = self._bounds(tasks)
        if self.config.place_with_mean_at_eval:
            bounds = cloud_box(cloud.points, bounds)
        return cloud, tasks, bounds

    @property
    def _device(self) -> torch.device:
        return self.network.pos_encoding.device

    def _frame_weights(self, batch: dict[str, Any], bc: Tensor) -> Tensor:
        """(B,) BC weights: ``first_keyframe_weight`` on an episode's first frame (timestamp 0), 1 elsewhere, scaled
        to mean 1."""
        w = self.config.first_keyframe_weight
        if w == 1.0:
            return torch.ones_like(bc)
        first = first_frames(batch, bc.shape[0], bc.device, "first_keyframe_weight")
        weights = torch.where(first, w, 1.0).to(bc.dtype)
        return weights / weights.mean()

    def _instruction_negatives(
        self,
        views: Tensor,
        tasks: list[str],
        batch: dict[str, Any],
        bounds: Tensor,
        transforms: Tensor,
        target_uv: Tensor,
    ) -> Tensor:
        """(B,) each first frame's instruction negative (sigma_policy/instruction_contrast.py), the other instruction
        drawn from the policy's own stream; one network run on those rows."""
        b = len(tasks)

        def run_rows(idx: Tensor, asked: list[str]) -> NetworkOutput:
            sub = {
                k: v[idx] if isinstance(v, Tensor) and v.shape[:1] == (b,) else v for k, v in batch.items()
            }
            return self._run_network(views[idx], asked, sub, bounds[idx], transforms=transforms[idx])

        first = first_frames(batch, b, views.device, "instruction_negative_weight").tolist()
        cfg = self.config
        return instruction_negatives(
            run_rows,
            tasks,
            first,
            cfg.instruction_tasks,
            target_uv,
            cfg.instruction_negative_sigma_px,
            self._negative_draws,
        )

    def _bounds(self, tasks: list[str]) -> Tensor:
        """(B, 6) world box of each sample: its instruction's task box with ``per_task_bounds`` (an instruction
        the policy was not trained on gets ``scene_bounds``, with a warning once), else ``scene_bounds``."""
        boxes = self.config.task_boxes()
        if not boxes:
            return self.scene_bounds.expand(len(tasks), 6)
        unknown = {t for t in tasks if t not in boxes} - self._warned_instructions
        if unknown:
            logging.getLogger(__name__).warning(
                "no task box for instruction(s) %s: using scene_bounds %s",
                sorted(unknown),
                self.config.scene_bounds,
            )
            self._warned_instructions |= unknown
        union = self.config.scene_bounds
        return torch.tensor([boxes.get(t, union) for t in tasks], dtype=torch.float32, device=self._device)

    def _negative_groups(self, instructions: list[str], device: torch.device) -> Tensor | None:
        """(B,) ids for the state↔language term: rows sharing an id are not each other's negatives. With
        ``mask_same_task`` the id is the instruction's task (an instruction without one is its own task), with
        ``mask_same_instruction`` the instruction; None masks nothing."""
        cfg = self.config
        if cfg.mask_same_task:
            return instruction_ids([cfg.instruction_tasks.get(s, s) for s in instructions], device=device)
        return instruction_ids(instructions, device=device) if cfg.mask_same_instruction else None

    def _cloud(self, batch: dict[str, Any], t: int) -> Cloud:
        """Fused world-frame point cloud of all cameras at frame ``t`` (the depth unit checked on the first)."""
        cloud = camera_cloud(batch, self.config, t, check_depth=not self._depth_checked)
        self._depth_checked = True
        return cloud

    def _augmented_views(
        self, batch: dict[str, Any], t: int, pos: Tensor, quat: Tensor, bounds: Tensor, shift: float | Tensor
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Frame ``t``'s cloud under its own SE(3) draw about ``pos`` (B, 3) / ``quat`` (B, 4), rendered with the
        training render noise: ``(views, pos', quat', transforms)`` (sigma_policy/augmentation.py)."""
        cloud = self._cloud(batch, t)
        points, pos, quat, transforms = se3_augment(
            cloud.points,
            pos,
            quat,
            bounds,
            xyz_range=shift,
            yaw_range_deg=self.config.aug_yaw_range_deg,
        )
        views = add_render_noise(self._render(points, cloud.colors, bounds), self.config.image_noise)
        return views, pos, quat, transforms

    def _translation_range(self, bounds: Tensor) -> float | Tensor:
        """The augmentation's translation range now: metres, or with ``aug_translation_unit="box"`` per sample and
        axis (B, 3) or (3,) a share of ``bounds``' extent; scaled by the ramp's progress when it has one."""
        cfg = self.config
        scale = cfg.aug_translation_range
        if cfg.aug_translation_ramp_steps:  # a tensor: no device sync in the training step
            scale = scale * (self.aug_steps_taken / cfg.aug_translation_ramp_steps).clamp(max=1.0)
        if cfg.aug_translation_unit == "box":
            return scale * (bounds[..., 3:] - bounds[..., :3])
        return scale

    def _render(self, points: Tensor, colors: Tensor, bounds: Tensor) -> Tensor:
        """Crop to ``bounds`` ((6,) shared or (B, 6) per sample), map to the cube and render (B, V, 10, H, W)."""
        cube, colors, mask = crop_to_cube(points, colors, bounds)
        with torch.no_grad():
            return self.renderer(cube, colors, mask)

    def _language(self, tasks: list[str]) -> tuple[Tensor, Tensor]:
        """(B, L, D_tok) tokens and (B, D_sent) sentence features, cached on the policy device per instruction;
        with ``lang_task_contrast`` a training instruction's deviation from its task's mean is amplified
        (:meth:`_contrasted_states`)."""
        missing = [s for s in dict.fromkeys(tasks) if s not in self._lang_cache]
        if missing:
            feats = self.text_encoder.encode(missing)
            tokens = feats.tokens.detach().float()
            if self.config.lang_task_contrast:
                contrasted = self._contrasted_states()
                # an instruction outside the training set is read as it is
                tokens = torch.stack([contrasted.get(s, t) for s, t in zip(missing, tokens, strict=True)])
            for i, s in enumerate(missing):
                self._lang_cache[s] = (
                    tokens[i].to(self._device),
                    feats.sentence[i].detach().float().to(self._device),
                )
        tokens = torch.stack([self._lang_cache[s][0] for s in tasks])
        sentence = torch.stack([self._lang_cache[s][1] for s in tasks])
        return tokens, sentence

    def _contrasted_states(self) -> dict[str, Tensor]:
        """Each training instruction's token states as ``lang_task_contrast`` reads them: its task's mean plus the
        gain times its deviation from it (text_encoder.task_contrast); computed once."""
        if self._task_contrast is None:
            instructions = sorted(self.config.instruction_tasks)
            self._task_contrast = {}  # no task map: every instruction is read as it is
            if instructions:
                states = self.text_encoder.encode(instructions).tokens.detach().float()
                means, gain = task_contrast(states, [self.config.instruction_tasks[s] for s in instructions])
                self._task_contrast = dict(zip(instructions, means + gain * (states - means), strict=True))
        return self._task_contrast

    def _proprio(self, batch: dict[str, Any], bounds: Tensor, transforms: Tensor | None) -> Tensor | None:
        """The proprio token's input (sigma_policy/observation.py, ``proprio_input``)."""
        return proprio_input(batch, self.config, bounds, transforms, self._device)

    def _run_network(
        self,
        views: Tensor,
        tasks: list[str],
        batch: dict[str, Any],
        bounds: Tensor,
        goal_views: Tensor | None = None,
        transforms: Tensor | None = None,
        head_heatmap: Tensor | None = None,
        head_uv: Tensor | None = None,
    ) -> NetworkOutput:
        tokens, sentence = self._language(tasks)
        proprio = self._proprio(batch, bounds, transforms)
        device = views.device
        autocast = nullcontext()
        if self.config.use_bf16_autocast and device.type == "cuda" and torch.cuda.is_bf16_supported():
            autocast = torch.autocast("cuda", dtype=torch.bfloat16)
        elif self.config.use_cpu_bf16_autocast and device.type == "cpu" and cpu_has_native_bf16():
            autocast = torch.autocast("cpu", dtype=torch.bfloat16)
        network = self.acting_network()
        with autocast:
            return network(
                views,
                tokens,
                lang_sentence=sentence if goal_views is not None else None,
                goal_images=goal_views,
                proprio=proprio,
                head_heatmap=head_heatmap if network.local_encoder is not None else None,
                head_uv=head_uv,
                fusion=self.config.heatmap_fusion,
            )
