"""SigmaPolicy on a tiny keyframe dataset written with the real LeRobot writer: losses, inference, processors,
save/load; and (slow) proof that it learns: overfitting below 2 cm and following the instruction."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from lerobot.configs.types import NormalizationMode
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_policy, make_pre_post_processors

from sigma_policy.configuration_sigma import SigmaConfig
from sigma_policy.heatmap import heatmap_to_cube_point
from sigma_policy.modeling_sigma import SigmaPolicy, cpu_has_native_bf16
from sigma_policy.pointcloud import cube_to_world, world_to_cube
from sigma_policy.test_time import transform_points
from sigma_policy.views import ALL_VIEWS
from tests.sigma_policy.tiny_dataset import BOUNDS, write_tiny_keyframe_dataset

FAST = {"preset": "small", "img_size": 32, "patch_size": 8, "attn_dim": 64, "attn_heads": 2}


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory) -> Path:
    return write_tiny_keyframe_dataset(tmp_path_factory.mktemp("sigma") / "tiny", episodes=4, size=48)


def build(root: Path, **overrides):
    """Policy + processors + dataset the way ``lerobot-train`` builds them (depth read in mm, LeRobot's default)."""
    cfg = SigmaConfig(**({"device": "cpu", "scene_bounds": list(BOUNDS)} | FAST | overrides))
    probe = LeRobotDataset("local/sigma_tiny", root=root)
    ds = LeRobotDataset(
        "local/sigma_tiny", root=root, delta_timestamps=resolve_delta_timestamps(cfg, probe.meta)
    )
    policy = make_policy(cfg, ds_meta=ds.meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=ds.meta.stats)
    return cfg, policy, pre, post, ds


def training_batch(ds: LeRobotDataset, indices: list[int]) -> dict:
    return torch.utils.data.default_collate([ds[i] for i in indices])


def single_observation(root: Path, index: int) -> dict:
    item = LeRobotDataset("local/sigma_tiny", root=root)[index]
    return {k: v for k, v in item.items() if k.startswith("observation.") or k == "task"}


@pytest.mark.skipif(not cpu_has_native_bf16(), reason="this CPU has no native bf16 (AVX512-BF16/AMX)")
def test_cpu_bf16_autocast_runs_the_network_in_bf16_and_keeps_the_loss_and_weights_float32(tiny_root):
    """``use_cpu_bf16_autocast``: the network's matmuls run in bf16 (its logits come out bf16), the losses are
    computed in float32 from them and the weights the optimiser updates stay float32."""
    _, policy, pre, _, ds = build(tiny_root, use_cpu_bf16_autocast=True)
    batch = pre(training_batch(ds, [0, 1, 3, 4]))
    seen = {}
    hook = policy.network.register_forward_hook(lambda _m, _i, out: seen.update(dtype=out.trans.dtype))
    torch.manual_seed(0)
    loss, _ = policy.forward(batch)
    hook.remove()
    assert seen["dtype"] == torch.bfloat16
    assert loss.dtype == torch.float32 and torch.isfinite(loss)
    loss.backward()
    assert all(p.dtype == torch.float32 for p in policy.network.parameters())
    plain = build(tiny_root)[1]
    plain.load_state_dict(policy.state_dict())
    torch.manual_seed(0)
    assert abs(plain.forward(batch)[0].item() - loss.item()) < 0.05 * loss.item()  # same draws, float32


def test_forward_logs_every_loss_part_and_trains_only_the_network(tiny_root):
    cfg, policy, pre, _, ds = build(tiny_root)
    batch = pre(training_batch(ds, [0, 1, 3, 4]))  # frames 0 and 1 of two episodes (never the final frame)
    assert batch["observation.images.front"].shape[:2] == (4, 2)  # current + goal
    loss, info = policy.forward(batch)
    assert torch.isfinite(loss)
    expected = {"trans_loss", "rot_loss", "grip_loss", "collision_loss", "bc_loss", "contrastive_loss"}
    assert expected <= set(info)
    # One instruction in the batch and same-instruction masking: the state-language term has nothing to contrast.
    assert info["contrastive_sl_loss"] == 0.0 and info["contrastive_goal_loss"] > 0.0
    # Chance level of the translation CE is about log(H*W) per view.
    assert info["trans_loss"] > 0.5 * math.log(cfg.img_size**2)
    loss.backward()
    assert policy.network.contrastive.goal_pos_encoding.grad.abs().sum() > 0
    assert all(not k.startswith("text_encoder") for k in policy.state_dict())
    per_sample, _ = policy.forward(batch, reduction="none")
    assert per_sample.shape == (4,)


def test_rvt_baseline_without_contrastive_loss(tiny_root):
    cfg, policy, pre, _, ds = build(tiny_root, use_contrastive=False)
    assert cfg.observation_delta_indices == [0]
    batch = pre(training_batch(ds, [0, 1]))
    loss, info = policy.forward(batch)
    assert "contrastive_loss" not in info and loss.item() == pytest.approx(info["bc_loss"], rel=1e-5)
    assert policy.network.contrastive is None


def test_first_keyframe_weight_scales_the_first_frames_bc_loss_and_keeps_the_batch_mean(tiny_root):
    """Frames 0 and 1 of two episodes: with weight 3 the two first frames get 3 / 2 and the others 1 / 2 of their
    unweighted BC loss (weights scaled to mean 1), from the same draws."""
    _, plain, pre, _, ds = build(tiny_root, use_contrastive=False)
    _, weighted, *_ = build(tiny_root, use_contrastive=False, first_keyframe_weight=3.0)
    weighted.load_state_dict(plain.state_dict())
    batch = pre(training_batch(ds, [0, 1, 3, 4]))
    first = batch["timestamp"] == 0  # frame_index does not pass LeRobot's processors; the timestamp does
    assert first.tolist() == [True, False, True, False]
    torch.manual_seed(0)
    base, _ = plain.forward(batch, reduction="none")
    torch.manual_seed(0)
    scaled, _ = weighted.forward(batch, reduction="none")
    torch.testing.assert_close(scaled, base * torch.where(first, 1.5, 0.5))
    del batch["timestamp"]
    with pytest.raises(KeyError, match="timestamp"):
        weighted.forward(batch)
    with pytest.raises(ValueError, match="first_keyframe_weight"):
        SigmaConfig(first_keyframe_weight=0.0)


def test_task_contrast_reads_each_training_instruction_amplified_and_others_as_they_are(tiny_root):
    """``lang_task_contrast``: the two instructions of one task are read as their mean plus the gain times their
    deviation (sigma_policy/text_encoder.task_contrast); an instruction outside ``instruction_tasks`` is untouched."""
    pair = ["stack the red cube on the green cube", "stack the green cube on the red cube"]
    tasks = {pair[0]: "stack", pair[1]: "stack", "lift the cube": "lift"}
    _, policy, *_ = build(tiny_root, lang_task_contrast=True, instruction_tasks=tasks)
    _, plain, *_ = build(tiny_root)
    read, sentence = policy._language([*pair, "lift the cube", "open the door"])
    raw, raw_sentence = plain._language([*pair, "lift the cube", "open the door"])
    mean = raw[:2].mean(0)
    gain = (read[0] - mean).norm() / (raw[0] - mean).norm()
    assert gain > 5
    torch.testing.assert_close(read[:2], mean + gain * (raw[:2] - mean))
    # lift is alone in its task; the door is not a training instruction
    torch.testing.assert_close(read[2:], raw[2:])
    torch.testing.assert_close(sentence, raw_sentence)
    _, unmapped, *_ = build(tiny_root, lang_task_contrast=True, instruction_tasks={})
    torch.testing.assert_close(unmapped._language(pair)[0], raw[:2])  # no task map: nothing to amplify


def test_unbatched_single_observation_inference(tiny_root):
    _, policy, pre, post, _ = build(tiny_root)
    policy.eval()
    obs = pre(single_observation(tiny_root, 1))
    action = post(policy.select_action(obs))
    assert action.shape == (1, 9) and action.device.type == "cpu"
    quat = action[0, 3:7]
    assert quat.norm().item() == pytest.approx(1.0, abs=1e-4) and quat[3] >= 0
    assert set(action[0, 7:].tolist()) <= {0.0, 1.0}
    lo, hi = torch.tensor(BOUNDS[:3]), torch.tensor(BOUNDS[3:])
    assert ((action[0, :3] >= lo - 1e-4) & (action[0, :3] <= hi + 1e-4)).all()
    pred = policy.last_prediction
    assert pred.views.shape == (1, 5, 10, 32, 32)
    torch.testing.assert_close(pred.heatmaps.sum((-1, -2)), torch.ones(1, 5))
    assert pred.point_world.shape == (1, 3)
    # The rendered views contain points: the RGB channels of the top view are not all empty.
    assert pred.views[0, 0, 3:6].abs().sum() > 0


def test_input_cloud_is_what_predict_renders_without_running_the_network(tiny_root, monkeypatch):
    _, policy, pre, _, _ = build(tiny_root)
    policy.eval()
    obs = pre(single_observation(tiny_root, 1))
    pred = policy.predict(obs)
    monkeypatch.setattr(policy, "_run_network", lambda *a, **k: pytest.fail("input_cloud ran the network"))
    points, colors, bounds = policy.input_cloud(obs)
    torch.testing.assert_close(points, pred.cloud_points, equal_nan=True)
    torch.testing.assert_close(colors, pred.cloud_colors)
    torch.testing.assert_close(bounds, pred.bounds)


def test_yaw_ensemble_turns_the_cloud_and_the_hand_and_turns_each_prediction_back(tiny_root):
    """``tta_yaw_deg``: each extra pass renders the cloud turned about the box's centre line, with the gripper's
    pose the proprio token reads turned with it; with a radius that takes every pass in, the action's position is
    the mean of the passes' points turned back."""
    cfg, policy, pre, _, _ = build(tiny_root, tta_yaw_deg=[-90, 45], tta_radius_m=10.0)
    policy.eval()
    obs = pre(single_observation(tiny_root, 1))
    rendered, proprios, points, turns = [], [], [], []
    render, proprio, run_network = policy._render, policy._proprio, policy._run_network

    def spy_render(points, colors, bounds):
        rendered.append(points)
        return render(points, colors, bounds)

    def spy_proprio(batch, bounds, transforms):
        turns.append(transforms)
        proprios.append(proprio(batch, bounds, transforms))
        return proprios[-1]

    def spy_network(views, tasks, batch, bounds, transforms=None, **kwargs):
        out = run_network(views, tasks, batch, bounds, transforms=transforms, **kwargs)
        cube = heatmap_to_cube_point(
            out.trans.float(), cfg.img_size, refine_px=cfg.heatmap_refine_px, fusion=cfg.heatmap_fusion
        )
        world = cube_to_world(cube, bounds)
        points.append(world if transforms is None else transform_points(transforms, world, inverse=True))
        return out

    policy._render, policy._proprio, policy._run_network = spy_render, spy_proprio, spy_network
    pred = policy.predict(obs)
    assert len(rendered) == 3 and turns[0] is None
    centre = (pred.bounds[:, :3] + pred.bounds[:, 3:]) / 2
    for shown, T, degrees in zip(rendered[1:], turns[1:], (-90, 45), strict=True):
        torch.testing.assert_close(shown, transform_points(T, pred.cloud_points), equal_nan=True)
        torch.testing.assert_close(transform_points(T, centre), centre)
        assert torch.rad2deg(torch.atan2(T[0, 1, 0], T[0, 0, 0])).item() == pytest.approx(degrees)
    # proprio = [gripper (3), grip site in the box (3), orientation columns (6)]: the turned passes' site moved
    assert not torch.allclose(proprios[1][:, 3:6], proprios[0][:, 3:6])
    # every pass within the radius: the position is the mean of the passes' points, each turned back
    torch.testing.assert_close(pred.action[:, :3], torch.stack(points).mean(0))


def test_yaw_ensemble_whose_passes_all_disagree_acts_as_the_unturned_pass(tiny_root):
    _, policy, pre, _, _ = build(tiny_root)
    policy.eval()
    obs = pre(single_observation(tiny_root, 1))
    plain = policy.predict(obs)
    policy.config.tta_yaw_deg, policy.config.tta_radius_m = [-30, 30], 1e-9
    ensembled = policy.predict(obs)
    torch.testing.assert_close(ensembled.action, plain.action)
    torch.testing.assert_close(ensembled.point_cube, plain.point_cube)


def test_calibration_keys_survive_the_preprocessor_unnormalised(tiny_root):
    mapping = {
        "VISUAL": NormalizationMode.MEAN_STD,
        "STATE": NormalizationMode.MEAN_STD,
        "ACTION": NormalizationMode.IDENTITY,
    }
    _, _, pre, _, _ = build(
        tiny_root, normalization_mapping=mapping, normalize_observation_keys=["observation.state"]
    )
    raw = single_observation(tiny_root, 1)
    out = pre(dict(raw))
    for cam in ("front", "side"):
        for key in (f"observation.camera.{cam}.intrinsics", f"observation.camera.{cam}.extrinsics"):
            torch.testing.assert_close(out[key][0], raw[key])
        torch.testing.assert_close(
            out[f"observation.images.{cam}_depth"][0], raw[f"observation.images.{cam}_depth"]
        )
    assert not torch.allclose(out["observation.state"][0], raw["observation.state"])  # the whitelisted key is


def test_save_and_reload_policy_and_processors(tiny_root, tmp_path):
    _, policy, pre, post, _ = build(tiny_root)
    policy.eval()
    obs = single_observation(tiny_root, 4)
    before = post(policy.select_action(pre(dict(obs))))
    policy.save_pretrained(tmp_path)
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    loaded = SigmaPolicy.from_pretrained(tmp_path)
    pre2, post2 = make_pre_post_processors(loaded.config, pretrained_path=str(tmp_path))
    assert loaded.config.img_size == 32 and loaded.config.preset == "small"
    after = post2(loaded.select_action(pre2(dict(obs))))
    torch.testing.assert_close(after, before)


def test_translation_range_in_box_units_grows_over_its_ramp_and_resumes_from_the_checkpoint(
    tiny_root, tmp_path
):
    _, policy, pre, _, ds = build(
        tiny_root, aug_translation_range=0.125, aug_translation_unit="box", aug_translation_ramp_steps=4
    )
    extent = torch.tensor(BOUNDS[3:]) - torch.tensor(BOUNDS[:3])
    bounds = policy.scene_bounds
    torch.testing.assert_close(policy._translation_range(bounds), 0.0 * extent)
    batch = pre(training_batch(ds, sample_indices(ds)[:2]))
    for _ in range(2):
        policy.forward(dict(batch))
    with torch.no_grad():  # an evaluation pass is not a training step
        policy.forward(dict(batch))
    torch.testing.assert_close(policy._translation_range(bounds), 0.0625 * extent)
    policy.save_pretrained(tmp_path)
    resumed = SigmaPolicy.from_pretrained(tmp_path)
    assert int(resumed.aug_steps_taken) == 2
    for _ in range(3):
        resumed.forward(dict(batch))
    torch.testing.assert_close(resumed._translation_range(bounds), 0.125 * extent)  # full from step 4 on
    assert "aug_steps_taken" not in dict(build(tiny_root)[1].named_buffers())  # no ramp, no new key


def test_weight_average_follows_the_trained_weights_acts_outside_training_and_resumes(tiny_root, tmp_path):
    _, policy, pre, _, ds = build(tiny_root, ema_decay=0.5)
    average = policy.weight_average
    trained_ids = {id(p) for group in policy.get_optim_params() for p in group["params"]}
    assert trained_ids == {id(p) for p in policy.network.parameters()}  # the average is never trained
    optimiser = torch.optim.SGD(policy.network.parameters(), lr=0.1)
    batch = pre(training_batch(ds, sample_indices(ds)[:2]))
    snapshots = []
    for _ in range(2):
        optimiser.zero_grad()
        policy.forward(dict(batch))[0].backward()
        optimiser.step()
        policy.update()  # what lerobot-train calls after every optimiser step
        snapshots.append({k: v.detach().clone() for k, v in policy.network.state_dict().items()})
    assert average.steps == 2
    for key, avg in average.network.state_dict().items():  # the first step copies, the second moves half-way
        torch.testing.assert_close(avg, (snapshots[0][key] + snapshots[1][key]) / 2)
    assert policy.acting_network() is policy.network  # training runs the trained weights
    policy.eval()
    assert policy.acting_network() is average.network
    obs = pre(dict(single_observation(tiny_root, 4)))
    with_average = policy.select_action(dict(obs))
    policy.config.act_with_ema = False
    assert policy.acting_network() is policy.network
    assert not torch.equal(policy.select_action(dict(obs)), with_average)
    policy.config.act_with_ema = True
    policy.save_pretrained(tmp_path)
    resumed = SigmaPolicy.from_pretrained(tmp_path).eval()
    assert resumed.weight_average.steps == 2
    torch.testing.assert_close(resumed.select_action(dict(obs)), with_average)
    assert not any(
        k.startswith("weight_average") for k in build(tiny_root)[1].state_dict()
    )  # off: no new keys
    with pytest.raises(ValueError, match=r"ema_decay must be in \[0, 1\)"):
        SigmaConfig(device="cpu", ema_decay=1.0)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [("aug_translation_unit", "cm", "'m' or 'box'"), ("aug_translation_ramp_steps", -1, ">= 0")],
)
def test_translation_augmentation_options_are_checked(field, value, message):
    with pytest.raises(ValueError, match=message):
        SigmaConfig(device="cpu", **{field: value})


def test_checkpoint_saved_without_film_loads_without_it(tiny_root, tmp_path, caplog):
    """A small-preset checkpoint from before ``lang_film`` existed (no field in config.json, no FiLM weights)
    loads without the module instead of with a randomly initialised one (LeRobot loads non-strictly)."""
    import json

    _, policy, pre, _, _ = build(tiny_root, lang_film=False)
    policy.eval()
    obs = single_observation(tiny_root, 4)
    before = policy.select_action(pre(dict(obs)))
    policy.save_pretrained(tmp_path)
    config = json.loads((tmp_path / "config.json").read_text())
    del config["lang_film"]  # as written before the field existed
    (tmp_path / "config.json").write_text(json.dumps(config))
    with caplog.at_level("WARNING"):
        loaded = SigmaPolicy.from_pretrained(tmp_path)
    assert "no instruction-FiLM weights" in caplog.text
    assert loaded.network.lang_film is None and loaded.config.lang_film is False
    torch.testing.assert_close(loaded.select_action(pre(dict(obs))), before)


def test_checkpoint_saved_without_proprio_film_loads_without_it(tiny_root, tmp_path, caplog):
    """A checkpoint whose config asks for ``proprio_film`` (as a later preset may) but whose weights have none
    loads without the module, and acts as saved."""
    import json

    _, policy, pre, _, _ = build(tiny_root, use_proprio=True, proprio_film=False)
    policy.eval()
    obs = single_observation(tiny_root, 4)
    before = policy.select_action(pre(dict(obs)))
    policy.save_pretrained(tmp_path)
    config = json.loads((tmp_path / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps(config | {"proprio_film": True}))
    with caplog.at_level("WARNING"):
        loaded = SigmaPolicy.from_pretrained(tmp_path)
    assert "no proprio-FiLM weights" in caplog.text
    assert loaded.network.proprio_film is None and loaded.config.proprio_film is False
    torch.testing.assert_close(loaded.select_action(pre(dict(obs))), before)


def test_depth_unit_mismatch_is_reported(tiny_root):
    _, policy, pre, _, ds = build(tiny_root, depth_unit="m")  # the dataset returns millimetres
    with pytest.raises(ValueError, match="depth_unit"):
        policy.forward(pre(training_batch(ds, [0, 1])))


def test_missing_calibration_feature_is_reported(tiny_root):
    cfg, *_ = build(tiny_root)
    features = dict(cfg.input_features)
    features.pop("observation.camera.side.extrinsics")
    cfg.input_features = features
    with pytest.raises(ValueError, match=r"camera 'side'.*extrinsics"):
        cfg.validate_features()


# ------------------------------------------------------------------------------------------------ learning
def train(
    policy,
    pre,
    ds,
    indices: list[int],
    steps: int,
    batch_size: int = 8,
    seed: int = 0,
    distinct: bool = False,
) -> list[dict[str, float]]:
    """Train with the policy's own optimiser and schedule presets; return the logged loss parts per step.

    ``distinct`` draws each batch without replacement (no duplicate sample acting as its own negative).
    """
    torch.manual_seed(seed)
    cfg = policy.config
    opt = cfg.get_optimizer_preset().build(policy.get_optim_params())
    sched = cfg.get_scheduler_preset().build(opt, num_training_steps=steps)
    policy.train()
    log = []
    for _ in range(steps):
        if distinct:
            pick = torch.randperm(len(indices))[:batch_size].tolist()
        else:
            pick = torch.randint(0, len(indices), (batch_size,)).tolist()
        loss, info = policy.forward(pre(training_batch(ds, [indices[i] for i in pick])))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        log.append(info)
    policy.eval()
    return log


def translation_errors(policy, pre, root: Path, indices: list[int]) -> torch.Tensor:
    ds = LeRobotDataset("local/sigma_tiny", root=root)
    errors = []
    for i in indices:
        item = ds[i]
        obs = {k: v for k, v in item.items() if k.startswith("observation.") or k == "task"}
        errors.append((policy.select_action(pre(obs))[0, :3].cpu() - item["action"][:3]).norm())
    return torch.stack(errors)


def sample_indices(ds: LeRobotDataset) -> list[int]:
    """Every frame but the last of each episode (the final frame is a goal only)."""
    ep = ds.meta.episodes
    return [
        i
        for a, b in zip(ep["dataset_from_index"], ep["dataset_to_index"], strict=True)
        for i in range(a, b - 1)
    ]


@pytest.mark.slow
def test_small_overfits_the_tiny_dataset_below_2cm(tmp_path):
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=4, size=64)
    _, policy, pre, _, ds = build(
        root, preset="small", img_size=64, attn_dim=128, attn_heads=4, image_noise=0.0
    )
    idx = sample_indices(ds)
    train(policy, pre, ds, idx, steps=250)
    errors = translation_errors(policy, pre, root, idx)
    assert errors.max().item() < 0.02, errors


@pytest.mark.slow
def test_prediction_follows_the_instruction(tmp_path):
    root = write_tiny_keyframe_dataset(tmp_path / "lang", episodes=2, size=64, scenes="language")
    _, policy, pre, _, ds = build(
        root, preset="small", img_size=64, attn_dim=128, attn_heads=4, image_noise=0.0
    )
    idx = sample_indices(ds)  # the same scene under "reach the red cube" and "reach the blue cube"
    train(policy, pre, ds, idx, steps=250)
    full = LeRobotDataset("local/sigma_tiny", root=root)
    for i in idx:
        item = full[i]
        obs = {k: v for k, v in item.items() if k.startswith("observation.")}
        preds = {}
        for task in ("reach the red cube", "reach the blue cube"):
            preds[task] = policy.select_action(pre(obs | {"task": task}))[0, :3].cpu()
        own = preds[item["task"]]
        other = preds[next(t for t in preds if t != item["task"])]
        assert (own - item["action"][:3]).norm() < 0.03, (i, item["task"], own, item["action"][:3])
        assert (other - own).norm() > 0.1  # the other instruction points at the other cube (~28 cm away)


@pytest.mark.slow
def test_contrastive_loss_falls_well_below_chance(tmp_path):
    """The full policy's (state, language) <-> goal InfoNCE, from rendered clouds to features, learns.

    Eight episodes with the cube at different places: each sample's goal (the next keyframe) identifies its
    episode. Augmentation is off so that the goal render keeps the cube where the current one has it (with
    independent SE(3) draws on a single-task scene, goals of the same stage differ only by the random
    transform, and the term cannot go far below log(batch)). The features are centred (``contrastive_center``):
    uncentred, this term sat at log(8) for 50 steps and then near log(4) up to step 600, telling the two stages
    apart but not the cube's place (docs/learning.md "Centred contrastive features").
    """
    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=8, size=48)
    _, policy, pre, _, ds = build(
        root, image_noise=0.0, aug_translation_range=0.0, aug_yaw_range_deg=0.0, contrastive_center=True
    )
    idx = sample_indices(ds)
    batch = 8
    log = train(policy, pre, ds, idx, steps=150, batch_size=batch, distinct=True)
    chance = math.log(batch)
    first = sum(s["contrastive_goal_loss"] for s in log[:5]) / 5
    last = sum(s["contrastive_goal_loss"] for s in log[-10:]) / 10
    assert first > 0.8 * chance  # it starts near chance ...
    assert last < 0.5 * chance, (first, last)  # ... and ends well below it


def test_scene_box_comes_from_the_dataset_sidecar_when_unset(tmp_path):
    import json

    root = write_tiny_keyframe_dataset(tmp_path / "tiny", episodes=1, size=32)
    sidecar = root / "meta" / "sigma.json"
    side = json.loads(sidecar.read_text()) if sidecar.exists() else {}
    side["bounds"] = {"a": [-0.3, -0.2, 0.7, 0.3, 0.3, 1.3], "b": [-0.4, -0.3, 0.75, 0.2, 0.35, 1.2]}
    sidecar.write_text(json.dumps(side))
    probe = LeRobotDataset("local/sigma_tiny", root=root)

    cfg = SigmaConfig(device="cpu", **FAST)
    assert cfg.scene_bounds is None
    policy = make_policy(cfg, ds_meta=probe.meta)
    assert cfg.scene_bounds == pytest.approx([-0.4, -0.3, 0.7, 0.3, 0.35, 1.3])  # the union, saved in config
    assert policy.scene_bounds.tolist() == pytest.approx(cfg.scene_bounds)

    given = SigmaConfig(device="cpu", scene_bounds=list(BOUNDS), **FAST)
    make_policy(given, ds_meta=probe.meta)
    assert given.scene_bounds == list(BOUNDS)  # an explicit box always wins

    sidecar.unlink()
    bare = SigmaConfig(device="cpu", **FAST)
    make_policy(bare, ds_meta=LeRobotDataset("local/sigma_tiny", root=root).meta)
    from sigma_policy.configuration_sigma import DEFAULT_SCENE_BOUNDS

    assert bare.scene_bounds == DEFAULT_SCENE_BOUNDS


def test_augmented_target_lands_on_the_augmented_cube_inside_forward(tiny_root, monkeypatch):
    """Augmentation, render and target composed as ``SigmaPolicy.forward`` composes them: under a random yaw and
    shift, the heatmap target of every start frame (the pre-grasp pose, straight above the cube centre) lies on
    the red cube in the rendered top view. (Targets left unshifted while the cloud moves fail this test.)"""
    import sigma_policy.modeling_sigma as modeling

    captured = {}
    render = SigmaPolicy._render
    heatmaps = modeling.gaussian_heatmaps

    def keep_views(self, points, colors, bounds):
        captured.setdefault("views", render(self, points, colors, bounds))
        return captured["views"]

    def keep_uv(uv, *args, **kwargs):
        captured["uv"] = uv
        return heatmaps(uv, *args, **kwargs)

    monkeypatch.setattr(SigmaPolicy, "_render", keep_views)
    monkeypatch.setattr(modeling, "gaussian_heatmaps", keep_uv)
    _, policy, pre, _, ds = build(
        tiny_root,
        image_noise=0.0,
        aug_translation_range=0.1,
        aug_yaw_range_deg=45.0,
        use_contrastive=False,
    )
    idx = sample_indices(ds)
    torch.manual_seed(3)
    policy.forward(pre(training_batch(ds, idx)))
    views, uv = captured["views"], captured["uv"]  # (B, V, 10, S, S), (B, V, 2)
    top = views[:, 0, 3:6]  # RGB of the top view
    size = views.shape[-1]
    # Frame 0's goal is the pre-grasp pose above the cube (frame 1's, the grasp, hides under the gripper marker).
    starts = [k for k, i in enumerate(idx) if int(ds[i]["frame_index"]) == 0]
    assert starts
    for k in starts:
        col, row = (uv[k, 0].floor().long().clamp(0, size - 1)).tolist()
        r, g, b = top[k, :, row, col].tolist()
        assert r > 0.5 and g < 0.3 and b < 0.3, (k, (row, col), (r, g, b))


def test_checkpoint_saved_before_proprio_position_loads_with_its_gripper_only_token(
    tiny_root, tmp_path, caplog
):
    import json

    _, policy, pre, _, _ = build(
        tiny_root, use_proprio=True, proprio_position=False, proprio_orientation=False, proprio_in_heads=False
    )
    policy.eval()
    obs = single_observation(tiny_root, 4)
    before = policy.select_action(pre(dict(obs)))
    policy.save_pretrained(tmp_path)
    config = json.loads((tmp_path / "config.json").read_text())
    del config["proprio_position"]  # as written before the field existed; the small preset now turns it on
    (tmp_path / "config.json").write_text(json.dumps(config))
    with caplog.at_level("WARNING"):
        loaded = SigmaPolicy.from_pretrained(tmp_path)
    assert "gripper-only proprio token" in caplog.text and loaded.config.proprio_position is False
    torch.testing.assert_close(loaded.select_action(pre(dict(obs))), before)


def test_proprio_position_is_the_grip_site_in_the_box_moved_like_the_cloud(tiny_root):
    """The proprio token gets the grip site's box coordinates; under augmentation the same rigid transform as the
    cloud and the target moves it, so position and images agree."""
    _, policy, pre, _, ds = build(
        tiny_root, use_proprio=True, proprio_position=True, proprio_orientation=False
    )
    batch = pre(training_batch(ds, [0, 1]))
    state = batch["observation.state"][:, 0].float()
    plain = policy._proprio(batch, policy.scene_bounds, None)
    assert plain.shape == (2, 6)
    torch.testing.assert_close(plain[:, :3], state[:, 7:10])
    torch.testing.assert_close(plain[:, 3:], world_to_cube(state[:, :3], policy.scene_bounds))
    shift = torch.eye(4).repeat(2, 1, 1)
    shift[:, :3, 3] = torch.tensor([0.05, -0.02, 0.01])
    moved = policy._proprio(batch, policy.scene_bounds, shift)
    torch.testing.assert_close(
        moved[:, 3:], world_to_cube(state[:, :3] + shift[:, :3, 3], policy.scene_bounds)
    )


def test_proprio_orientation_is_the_grip_site_rotation_turned_like_the_cloud(tiny_root):
    """With ``proprio_orientation`` the token also holds the first two columns of the grip site's rotation
    matrix (sign-free, continuous), rotated by the augmentation's rotation like the cloud and the target."""
    from sigma_policy.rotation import quat_to_matrix

    _, policy, pre, _, ds = build(
        tiny_root, use_proprio=True, proprio_position=True, proprio_orientation=True
    )
    batch = pre(training_batch(ds, [0, 1]))
    state = batch["observation.state"][:, 0].float()
    plain = policy._proprio(batch, policy.scene_bounds, None)
    assert plain.shape == (2, 12) and policy.network.proprio_preprocess.linear.in_features == 12
    R = quat_to_matrix(state[:, 3:7])
    torch.testing.assert_close(plain[:, 6:], R[:, :, :2].transpose(1, 2).flatten(1))
    yaw = torch.tensor(0.7)
    turn = torch.eye(4).repeat(2, 1, 1)
    turn[:, :2, :2] = torch.tensor([[yaw.cos(), -yaw.sin()], [yaw.sin(), yaw.cos()]])
    moved = policy._proprio(batch, policy.scene_bounds, turn)
    torch.testing.assert_close(moved[:, 6:], (turn[:, :3, :3] @ R)[:, :, :2].transpose(1, 2).flatten(1))


def test_checkpoint_saved_before_the_head_inputs_loads_as_saved(tiny_root, tmp_path, caplog):
    """A checkpoint whose config.json predates ``local_channels``, ``proprio_orientation`` and ``proprio_in_heads``
    (fields absent, so a preset that turns them on would build modules the file lacks) loads with the network it
    was saved with."""
    import json

    _, policy, pre, _, _ = build(
        tiny_root,
        use_proprio=True,
        proprio_position=True,
        proprio_orientation=False,
        proprio_in_heads=False,
        local_channels=0,
    )
    policy.eval()
    obs = single_observation(tiny_root, 4)
    before = policy.select_action(pre(dict(obs)))
    policy.save_pretrained(tmp_path)
    config = json.loads((tmp_path / "config.json").read_text())
    config |= {"local_channels": 8, "proprio_orientation": True, "proprio_in_heads": True}  # a newer preset's
    (tmp_path / "config.json").write_text(json.dumps(config))
    with caplog.at_level("WARNING"):
        loaded = SigmaPolicy.from_pretrained(tmp_path)
    assert "no local head features" in caplog.text and "6-D proprio token" in caplog.text
    assert "without the proprio input" in caplog.text
    assert loaded.network.local_encoder is None and loaded.config.proprio_orientation is False
    assert loaded.config.proprio_in_heads is False
    torch.testing.assert_close(loaded.select_action(pre(dict(obs))), before)


def test_per_task_bounds_give_each_instruction_its_task_box(tiny_root):
    """With ``per_task_bounds`` every sample is cropped, rendered and labelled in its own instruction's box; an
    instruction without a box falls back to ``scene_bounds``."""
    small_box = [-0.3, -0.3, 0.7, 0.3, 0.3, 1.3]
    instruction = str(LeRobotDataset("local/sigma_tiny", root=tiny_root)[0]["task"])
    _, policy, pre, _, ds = build(
        tiny_root, per_task_bounds=True, instruction_bounds={instruction: small_box}
    )
    union = torch.tensor(BOUNDS, dtype=torch.float32)
    boxes = policy._bounds([instruction, "an instruction never seen"])
    torch.testing.assert_close(boxes, torch.stack([torch.tensor(small_box), union]))
    batch = pre(training_batch(ds, [0, 1]))
    loss, _ = policy.forward(batch)
    assert torch.isfinite(loss)
    policy.eval()
    pred = policy.predict(batch | {"task": [instruction, "an instruction never seen"]})  # frame 0 of each
    torch.testing.assert_close(pred.bounds, boxes)


def test_per_task_bounds_are_read_from_the_dataset_sidecar(tmp_path):
    """``instruction_bounds`` come from the sidecar: each episode's instruction gets its task's recorded box."""
    import json

    from sigma_data.contract import SIDECAR, recorded_instruction_bounds, recorded_instruction_tasks

    sidecar = {
        "bounds": {
            "lift": [-0.18, -0.18, 0.75, 0.18, 0.18, 1.11],
            "pick_place": [-0.4, -0.5, 0.75, 0.6, 0.5, 1.75],
        },
        "episodes": [
            {"task": "lift", "instruction": "lift the cube"},
            {"task": "pick_place", "instruction": "put the milk in its bin"},
        ],
    }
    (tmp_path / SIDECAR).parent.mkdir(parents=True)
    (tmp_path / SIDECAR).write_text(json.dumps(sidecar))
    expected = {
        "lift the cube": sidecar["bounds"]["lift"],
        "put the milk in its bin": sidecar["bounds"]["pick_place"],
    }
    assert recorded_instruction_bounds(tmp_path) == expected
    cfg = SigmaConfig(preset="small", device="cpu", per_task_bounds=True, mask_same_task=True)
    assert cfg.fill_from_dataset(tmp_path) == [-0.4, -0.5, 0.75, 0.6, 0.5, 1.75]
    assert cfg.instruction_bounds == expected
    assert cfg.instruction_tasks == {"lift the cube": "lift", "put the milk in its bin": "pick_place"}
    assert recorded_instruction_bounds(tmp_path / "missing") == {}
    assert recorded_instruction_tasks(tmp_path / "missing") == {}


def test_yaw_scan_refuses_a_box_not_square_in_x_y():
    """The yaw scan's turned crop is a turn in the world only on square pixels: a box the policy renders with must
    be as wide in x as in y; with per-task boxes those are checked, not the union."""
    wide = [-0.4, -0.5, 0.75, 0.6, 0.6, 1.75]  # 1.0 m x 1.1 m
    with pytest.raises(ValueError, match=r"scene_bounds = .* is 1\.000 m x 1\.100 m"):
        SigmaConfig(preset="small", device="cpu", yaw_scan_px=24, scene_bounds=wide).fill_from_dataset()
    cfg = SigmaConfig(preset="small", device="cpu", yaw_scan_px=24, per_task_bounds=True, scene_bounds=wide)
    cfg.instruction_bounds = {"lift the cube": [-0.18, -0.18, 0.75, 0.18, 0.18, 1.11]}
    assert cfg.fill_from_dataset() == wide  # the union is only a fallback
    cfg.instruction_bounds["open the door"] = [-0.35, -0.55, 0.75, 0.35, 0.25, 1.45]
    with pytest.raises(ValueError, match=r"instruction_bounds\['open the door'\]"):
        cfg.fill_from_dataset()
    SigmaConfig(preset="small", device="cpu", scene_bounds=wide).fill_from_dataset()  # no scan: any box


def test_mask_same_task_leaves_no_state_language_negatives_from_the_same_task(tiny_root):
    """``mask_same_task``: the other variations of a task are not negatives of the state↔language term (a batch of
    one task's two instructions has none left, so the term is 0); with ``mask_same_instruction`` alone they are."""
    red, blue = "reach the red cube", "reach the blue cube"
    tasks = {red: "reach", blue: "reach", "lift the cube": "lift"}
    _, policy, pre, _, ds = build(tiny_root, mask_same_task=True, instruction_tasks=tasks)
    ids = policy._negative_groups([red, blue, "lift the cube", "an instruction never seen"], "cpu").tolist()
    assert ids[0] == ids[1] and len({ids[0], ids[2], ids[3]}) == 3
    batch = pre(training_batch(ds, [0, 1, 3, 4])) | {"task": [red, blue, red, blue]}
    torch.manual_seed(0)
    _, info = policy.forward(batch)
    assert info["contrastive_sl_loss"] == 0.0 and info["contrastive_goal_loss"] > 0
    policy.config.mask_same_task = False
    assert len(set(policy._negative_groups([red, blue], "cpu").tolist())) == 2
    torch.manual_seed(0)
    _, info = policy.forward(batch)
    assert info["contrastive_sl_loss"] > 0


def test_yaw_scan_crop_sits_at_the_target_in_training_and_at_the_prediction_at_inference(tiny_root):
    """With ``yaw_scan_px`` the scan's crop is centred within ``yaw_scan_jitter_px`` of the target's projections in
    training (the target heatmap's peak says where they are), and at inference the network places it itself."""
    _, policy, pre, post, ds = build(tiny_root, yaw_scan_px=8, yaw_scan_jitter_px=1.0)
    seen = {}
    policy.network.register_forward_hook(lambda _m, _a, kw, _o: seen.update(kw), with_kwargs=True)
    loss, _ = policy.forward(pre(training_batch(ds, [0, 1, 3, 4])))
    loss.backward()
    assert all(p.grad is not None for p in policy.network.yaw_scanner.parameters())
    heatmap, uv = seen["head_heatmap"], seen["head_uv"]
    size = heatmap.shape[-1]
    peak = heatmap.flatten(2).argmax(-1)
    peak_uv = torch.stack([peak % size, peak // size], dim=-1).float() + 0.5
    visible = heatmap.flatten(2).sum(-1) > 0
    assert ((uv - peak_uv).abs().amax(-1)[visible] <= 1.0 + 0.5 + 1e-4).all()
    policy.eval()
    seen.clear()
    action = post(policy.select_action(pre(single_observation(tiny_root, 1))))
    assert seen["head_uv"] is None and action.shape == (1, 9)


def capture_target_uv(monkeypatch) -> dict:
    """A dict that holds, under "uv", the pixel coordinates ``(B, V, 2)`` of the heatmap targets of the policy's
    latest training forward pass."""
    import sigma_policy.modeling_sigma as modeling

    captured = {}
    heatmaps = modeling.gaussian_heatmaps

    def keep_uv(uv, *args, **kwargs):
        captured["uv"] = uv
        return heatmaps(uv, *args, **kwargs)

    monkeypatch.setattr(modeling, "gaussian_heatmaps", keep_uv)
    return captured


def test_tilted_side_views_render_target_and_predict_in_one_geometry(tiny_root, monkeypatch):
    """With ``side_tilt_deg`` the renderer, the heatmap targets and the back-projection all use the tilted views:
    the side views' targets sit at the tilted projection (rows moved, columns and the top view not), training
    backpropagates, and inference back-projects to a finite action."""
    captured = capture_target_uv(monkeypatch)
    _, policy, pre, post, ds = build(tiny_root, side_tilt_deg=45.0, use_contrastive=False)
    assert policy.renderer.side_tilt_deg == 45.0 and policy.network.cfg.side_tilt_deg == 45.0
    loss, _ = policy.forward(pre(training_batch(ds, [0, 1, 3])))
    loss.backward()
    assert torch.isfinite(loss)
    tilted = captured["uv"]
    _, flat_policy, _, _, _ = build(tiny_root, use_contrastive=False)
    flat_policy.forward(pre(training_batch(ds, [0, 1, 3])))
    flat = captured["uv"]
    assert torch.equal(tilted[:, 0], flat[:, 0]) and torch.equal(tilted[..., 0], flat[..., 0])
    assert (tilted[:, 1:, 1] - flat[:, 1:, 1]).abs().max() > 1.0
    policy.eval()
    action = post(policy.select_action(pre(single_observation(tiny_root, 1))))
    assert action.shape == (1, 9) and torch.isfinite(action).all()


def test_three_virtual_views_train_save_reload_and_act_like_those_views_of_five(
    tiny_root, tmp_path, monkeypatch
):
    """``virtual_views`` (RVT-2's three): the policy renders only those views, its heatmap targets are the five-view
    policy's targets in those views, training backpropagates, and a saved policy reloads with its views and acts
    as before saving."""
    captured = capture_target_uv(monkeypatch)
    _, policy, pre, post, ds = build(tiny_root, virtual_views=["left", "top", "front"])
    assert policy.renderer.views == (0, 1, 3) and policy.network.cfg.num_views == 3
    batch = pre(training_batch(ds, [0, 1, 3]))
    torch.manual_seed(0)
    loss, _ = policy.forward(batch)
    loss.backward()
    assert torch.isfinite(loss) and captured["uv"].shape == (3, 3, 2)
    three = captured["uv"]
    _, five_policy, _, _, _ = build(tiny_root)
    torch.manual_seed(0)  # the same augmentation draw
    five_policy.forward(batch)
    torch.testing.assert_close(three, captured["uv"][:, [0, 1, 3]])
    policy.eval()
    obs = single_observation(tiny_root, 2)
    before = post(policy.select_action(pre(dict(obs))))
    assert before.shape == (1, 9) and torch.isfinite(before).all()
    assert policy.last_prediction.views.shape[1] == 3
    policy.save_pretrained(tmp_path)
    loaded = SigmaPolicy.from_pretrained(tmp_path)
    assert loaded.config.virtual_views == ["left", "top", "front"] and loaded.renderer.views == (0, 1, 3)
    torch.testing.assert_close(post(loaded.select_action(pre(dict(obs)))), before)


def test_inference_reads_no_state_when_nothing_uses_it(tiny_root):
    """Without the proprio token ``observation.state`` is not read at inference (RVT's inputs: the cameras and the
    instruction); with it, it is, and its absence is named."""
    obs = single_observation(tiny_root, 1)
    del obs["observation.state"]
    _, plain, pre, _, _ = build(tiny_root, use_proprio=False)
    plain.eval()
    assert torch.isfinite(plain.select_action(pre(dict(obs)))).all()
    _, proprio, *_ = build(tiny_root, use_proprio=True)
    proprio.eval()
    with pytest.raises(KeyError, match=r"observation\.state"):
        proprio.select_action(pre(dict(obs)))


def test_instruction_contrast_asks_the_tasks_other_instructions_and_runs_the_heads_at_the_contrasted_point(
    tiny_root,
):
    """``instruction_contrast``: the network runs once per instruction of the task, the action's point is the argmax of
    the contrasted heatmaps (returned as the prediction's heatmaps), and a last run pools the heads there; an
    instruction alone in its task runs once, as without the option."""
    from sigma_policy.heatmap import predicted_uv
    from sigma_policy.instruction_contrast import contrasted_logits

    cfg, policy, pre, _, _ = build(tiny_root, instruction_contrast=0.5, yaw_scan_px=8)
    policy.eval()
    obs = pre(single_observation(tiny_root, 1))
    own = obs["task"][0] if isinstance(obs["task"], list) else obs["task"]
    other = "an instruction of the same task"
    policy.config.instruction_tasks = {own: "the task", other: "the task"}
    calls = []
    run_network = policy._run_network

    def spy_network(views, tasks, batch, bounds, **kwargs):
        out = run_network(views, tasks, batch, bounds, **kwargs)
        calls.append((list(tasks), kwargs.get("head_uv"), out.trans.float()))
        return out

    policy._run_network = spy_network
    pred = policy.predict(obs)
    assert [c[0] for c in calls] == [[own], [other], [own]]
    assert calls[0][1] is None and calls[1][1] is None
    trans = contrasted_logits(calls[0][2], calls[1][2][None], torch.tensor([[True]]), 0.5)
    torch.testing.assert_close(calls[2][1], predicted_uv(trans, fusion=cfg.heatmap_fusion))
    torch.testing.assert_close(pred.heatmaps, torch.softmax(trans.flatten(2), -1).reshape(trans.shape))
    cube = heatmap_to_cube_point(
        trans, cfg.img_size, refine_px=cfg.heatmap_refine_px, fusion=cfg.heatmap_fusion
    )
    torch.testing.assert_close(pred.action[:, :3], cube_to_world(cube, pred.bounds))
    # alone in its task: one run
    policy.config.instruction_tasks = {own: "the task"}
    calls.clear()
    policy.predict(obs)
    assert [c[0] for c in calls] == [[own]]


def test_checkpoint_saved_with_retired_options_off_loads_and_acts_as_saved(tiny_root, tmp_path):
    """A checkpoint saved while the retired options existed names them all in config.json, off: it loads and
    acts as it did. One saved with a retired option on is refused, naming the file and the option
    (sigma_policy/compat.py)."""
    import json

    from sigma_policy.compat import RetiredOptionError

    _, policy, pre, _, _ = build(tiny_root)
    policy.eval()
    obs = single_observation(tiny_root, 4)
    before = policy.select_action(pre(dict(obs)))
    policy.save_pretrained(tmp_path)
    config = json.loads((tmp_path / "config.json").read_text())
    old = {  # as config.json held them until they were retired
        "stem_layers": 0,
        "hand_mask_box": None,
        "hand_mask_views": "all",
        "hand_marker": False,
        "hand_site_noise_m": 0.0,
        "zoom_box_m": 0.0,
        "zoom_share": 0.5,
        "zoom_jitter_m": 0.05,
        "zoom_at_inference": True,
    }
    (tmp_path / "config.json").write_text(json.dumps(config | old))
    loaded = SigmaPolicy.from_pretrained(tmp_path)
    torch.testing.assert_close(loaded.select_action(pre(dict(obs))), before)
    (tmp_path / "config.json").write_text(json.dumps(config | old | {"zoom_box_m": 0.5}))
    with pytest.raises(RetiredOptionError, match=rf"{tmp_path / 'config.json'}: policy\.zoom_box_m=0\.5"):
        SigmaPolicy.from_pretrained(tmp_path)


def test_policy_reads_instructions_from_a_feature_table_and_acts_the_same(tiny_root, tmp_path, monkeypatch):
    """With SIGMA_TEXT_FEATURES naming a table of its encoder (written from the dataset's tasks, as
    ``sigma-encode --dataset_root`` does), a saved policy loads without the encoder and acts exactly as before; an
    instruction the table lacks is refused by name (sigma_policy/text_encoder.py)."""
    from pipelines.encode import dataset_instructions
    from sigma_policy.text_encoder import TEXT_FEATURES_ENV, TextFeatureTable, save_text_features

    _, policy, pre, _, _ = build(tiny_root)
    policy.eval()
    obs = single_observation(tiny_root, 4)
    before = policy.select_action(pre(dict(obs)))
    policy.save_pretrained(tmp_path / "ckpt")
    table = save_text_features(
        policy.text_encoder, dataset_instructions(tiny_root), tmp_path / "f.safetensors"
    )
    monkeypatch.setenv(TEXT_FEATURES_ENV, str(table))
    loaded = SigmaPolicy.from_pretrained(tmp_path / "ckpt")
    assert isinstance(loaded.text_encoder, TextFeatureTable)
    torch.testing.assert_close(loaded.select_action(pre(dict(obs))), before, rtol=0, atol=0)
    loaded.reset()
    with pytest.raises(
        KeyError, match=r"f\.safetensors: no features for the instruction\(s\) \['fly away'\]"
    ):
        loaded.select_action(pre(dict(obs) | {"task": "fly away"}))


def test_instruction_negatives_ask_first_frames_the_other_instruction_and_add_its_unlikelihood(tiny_root):
    """``instruction_negative_weight``: only the batch's first frames whose task has another instruction are run
    again, under that instruction, and only their per-sample loss grows, by the weight times the unlikelihood of
    their own target there (inside BC); the rest of the loss, and the global random stream, are as without it."""
    red, blue = "reach the red cube", "reach the blue cube"
    tasks = {red: "reach", blue: "reach", "lift the cube": "lift"}
    _, plain, pre, _, ds = build(tiny_root, instruction_tasks=tasks)
    cfg, negative, *_ = build(tiny_root, instruction_tasks=tasks, instruction_negative_weight=2.0)
    negative.load_state_dict(plain.state_dict())
    batch = pre(training_batch(ds, [0, 1, 3, 4])) | {"task": [red, blue, "lift the cube", blue]}
    calls = []
    run_network = negative._run_network

    def spy_network(views, asked, sub, bounds, **kwargs):
        out = run_network(views, asked, sub, bounds, **kwargs)
        calls.append((list(asked), views.shape[0], sub["observation.state"].shape[0]))
        return out

    negative._run_network = spy_network
    torch.manual_seed(0)
    base, _ = plain.forward(batch, reduction="none")
    after_plain = torch.get_rng_state()
    torch.manual_seed(0)
    loss, info = negative.forward(batch, reduction="none")
    # the other instruction is drawn from a stream of its own: the rest of training draws as without the option
    assert torch.equal(torch.get_rng_state(), after_plain)
    # rows 0 and 2 are first frames; row 2's task (lift) has no other instruction
    assert calls[1] == ([blue], 1, 1)
    assert info["instruction_negative_loss"] > 0
    extra = loss - base  # BC's share of the total is bc_lambda
    assert extra[0].item() == pytest.approx(cfg.bc_lambda * 2.0 * info["instruction_negative_loss"], rel=1e-4)
    torch.testing.assert_close(extra[1:], torch.zeros(3), atol=1e-5, rtol=0)
    del batch["timestamp"]
    with pytest.raises(KeyError, match="instruction_negative_weight"):
        negative.forward(batch)
    with pytest.raises(ValueError, match="no instruction -> task map"):
        build(tiny_root, instruction_negative_weight=1.0)
    with pytest.raises(ValueError, match="instruction_negative_weight"):
        SigmaConfig(instruction_negative_weight=-1.0)


@pytest.mark.parametrize("fusion", ["sum", "product"])
def test_the_heads_read_where_the_policy_acts_whichever_heatmap_fusion(tiny_root, monkeypatch, fusion):
    """The yaw scan and the local features read at the predicted point's pixels: with ``heatmap_fusion`` those are
    the projections of the point the policy acts on, not of the point another fusion would pick (docs/method.md
    §14.6: product fusion without this moved the hand to the nut's handle and turned it for the ring)."""
    import sigma_policy.network as network_module
    from sigma_policy.heatmap import predicted_uv

    _, policy, pre, _, _ = build(tiny_root, yaw_scan_px=8, heatmap_fusion=fusion)
    policy.eval()
    read = []

    def recording(logits, side_tilt_deg=0.0, fusion="sum", views=ALL_VIEWS):
        read.append((fusion, predicted_uv(logits, side_tilt_deg, fusion, views)))
        return read[-1][1]

    monkeypatch.setattr(network_module, "predicted_uv", recording)
    pred = policy.predict(pre(single_observation(tiny_root, 1)))
    assert [f for f, _ in read] == [fusion]
    # the acted point's voxel, from the heatmaps the policy kept (log-probabilities: the same argmax as the logits)
    torch.testing.assert_close(read[0][1], predicted_uv(pred.heatmaps.log(), 0.0, fusion))
    with pytest.raises(ValueError, match="heatmap_fusion"):
        SigmaConfig(heatmap_fusion="mean")
