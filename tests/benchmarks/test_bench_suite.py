"""The suite benchmark's table: one column per training seed, a row per variation, pooled numbers per seed."""

from __future__ import annotations

import json

import draccus
import pytest

import sigma_policy.modeling_sigma
from benchmarks.bench_suite import (
    DEFAULT_BUDGET,
    FLOAT32_ARGS,
    FLOAT32_BUDGET,
    SUITE_ARGS,
    SuiteBenchConfig,
    markdown,
)
from benchmarks.training_runs import collect_train_and_heldout
from pipelines.collecting import demonstration_config


@pytest.fixture(autouse=True)
def native_bf16(monkeypatch):
    """The defaults these tests read are a CPU with native bf16's (the recipe's own budget) on any machine."""
    monkeypatch.setattr(sigma_policy.modeling_sigma, "cpu_has_native_bf16", lambda: True)


def _result(seed: int, successes: dict[str, int]) -> dict:
    stats = {"trans_cm_median": 0.4, "within_1cm": 0.9, "yaw_deg_mean": 10.0, "gripper_acc": 1.0}
    variations = [
        {
            "task": name.split(":")[0],
            "variation": name.split(":")[1],
            "successes": s,
            "episodes": 20,
            "ci95": [0.1, 0.9],
            "failures": {"dropped": 20 - s} if s < 20 else {},
        }
        for name, s in successes.items()
    ]
    return {
        "seed": seed,
        "train_seconds": 3600.0,
        "diagnostics": {"checkpoints": [{"train": {"all": stats}, "heldout": {"all": stats}}]},
        "eval": {"variations": variations, "seconds": 900.0},
    }


def test_markdown_has_a_column_per_seed_and_pooled_rows():
    cfg = SuiteBenchConfig(tasks=["lift", "stack"], seeds=[0, 1])
    results = [
        _result(0, {"lift:lift_cube": 20, "stack:red_on_green": 15}),
        _result(1, {"lift:lift_cube": 19, "stack:red_on_green": 12}),
    ]
    text = markdown(cfg, results)
    assert "| variation | seed 0 | seed 1 |" in text
    assert "| lift:lift_cube | 20/20 (10–90%) | 19/20 (10–90%) |" in text
    assert "| 0 | 0.40 | 0.40 | 90% | 10.0 | 100% | **35/40" in text
    assert "dropped 5" in text and "dropped 9" in text and "| 60 | 15 |" in text
    assert "`--policy.preset=suite` `--policy.use_cpu_bf16_autocast=true`" in text
    assert "decay over 7500 steps" in text  # the schedule stretched over the whole run by default
    short = markdown(SuiteBenchConfig(tasks=["lift"], schedule_steps=2000), results[:1])
    assert "decay over 2000 steps" in short


def test_learning_rate_option_reaches_lerobot_train_and_the_table():
    lift = [_result(0, {"lift:lift_cube": 20})]
    suite = SuiteBenchConfig(tasks=["lift"])
    assert suite.schedule_args == ["--policy.scheduler_decay_steps=7500"]  # the suite preset's lr
    assert "peak learning rate 0.003" in markdown(suite, lift)
    small = SuiteBenchConfig(tasks=["lift"], preset="small")  # the small preset's own 1e-2
    assert small.schedule_args == ["--policy.scheduler_decay_steps=7500"]
    assert "peak learning rate 0.01" in markdown(small, lift) and "`--policy.preset=small`" in markdown(
        small, lift
    )
    assert small.run_dir(0).name == "seed0_decay7500_lr0.01_small"  # a preset other than suite is named
    wide = SuiteBenchConfig(tasks=["lift"], batch_size=32, steps=3000)
    assert wide.run_dir(0).name == "seed0_decay3000_lr0.003_batch32"  # not the batch-8 run's directory
    gpu = SuiteBenchConfig(tasks=["lift"], preset="gpu", batch_size=64, steps=3000)
    # Not the suite network's batch-64 run:
    assert gpu.run_dir(0).name == "seed0_decay3000_lr0.003_batch64_gpu"
    # Runs that differ only in their policy options share a collection, not a directory:
    film = SuiteBenchConfig(tasks=["lift"], policy_args=[*SUITE_ARGS, "--policy.proprio_film=true"])
    assert film.run_dir(0).name == "seed0_decay7500_lr0.003_proprio_film-true"
    boxed = SuiteBenchConfig(tasks=["lift"], policy_args=["--policy.scene_bounds=[-0.2,0.2]"])
    assert (
        boxed.run_dir(0).name == "seed0_decay7500_lr0.003_scene_bounds--0.2,0.2_without-use_cpu_bf16_autocast"
    )
    tuned = SuiteBenchConfig(tasks=["lift"], lr=1e-3)
    assert tuned.schedule_args == ["--policy.scheduler_decay_steps=7500", "--policy.optimizer_lr=0.001"]


def test_the_budget_defaults_to_the_presets():
    suite = draccus.parse(SuiteBenchConfig, args=[])
    assert (suite.steps, suite.batch_size, suite.decay_steps) == (7500, 8, 7500)
    # the best five-task CPU recipe (docs/learning.md): every task, 50 demonstrations per variation
    assert (suite.tasks, suite.episodes) == (["lift", "stack", "pick_place", "nut_assembly", "door"], 50)
    gpu = draccus.parse(SuiteBenchConfig, args=["--preset", "gpu"])  # what docs/gpu.md measured, not 7500 × 8
    assert (gpu.steps, gpu.batch_size, gpu.decay_steps) == (3000, 64, 3000)
    assert gpu.run_dir(0).name == "seed0_decay3000_lr0.003_batch64_gpu"
    assert "--batch_size=64" in gpu.train_run(0, gpu.output_dir).command()
    given = draccus.parse(SuiteBenchConfig, args=["--preset", "gpu", "--steps", "1500", "--batch_size", "32"])
    assert (given.steps, given.batch_size, given.decay_steps) == (1500, 32, 1500)


def test_a_cpu_without_native_bf16_defaults_to_the_float32_budget(monkeypatch):
    """Without native bf16 the step runs in float32 at about twice the cost: unset ``--episodes`` and ``--steps``
    become ``FLOAT32_BUDGET`` (one seed within 2 hours on 2 cores), and the start line says so; naming either keeps
    the other at the bf16 recipe's value; the `gpu` preset and a GPU keep theirs. The float32 budget contrasts the
    tasks' instructions unless ``--policy_args`` name the option."""
    monkeypatch.setattr(sigma_policy.modeling_sigma, "cpu_has_native_bf16", lambda: False)
    plain = draccus.parse(SuiteBenchConfig, args=[])
    assert (plain.episodes, plain.steps, plain.batch_size) == (*FLOAT32_BUDGET, 8)
    assert (
        plain.policy_args == [*SUITE_ARGS, *FLOAT32_ARGS] == [*SUITE_ARGS, "--policy.lang_task_contrast=true"]
    )
    assert plain.run_dir(0).name == f"seed0_decay{FLOAT32_BUDGET[1]}_lr0.003_lang_task_contrast-true"
    assert "--policy.lang_task_contrast=true" in plain.train_run(0, plain.output_dir).command()
    assert "float32" in plain.budget_line() and f"--steps {DEFAULT_BUDGET[0]}" in plain.budget_line()
    assert "lang_task_contrast" in plain.budget_line()
    off = draccus.parse(SuiteBenchConfig, args=["--policy_args", "[--policy.lang_task_contrast=false]"])
    assert off.policy_args == ["--policy.lang_task_contrast=false"] and off.steps == FLOAT32_BUDGET[1]
    steps_given = draccus.parse(SuiteBenchConfig, args=["--steps", "3000", "--batch_size", "64"])
    # Scoring a GPU run's 50-per-variation data.
    assert (steps_given.episodes, steps_given.steps) == (50, 3000)
    assert "float32" not in steps_given.budget_line()
    episodes_given = draccus.parse(SuiteBenchConfig, args=["--episodes", "30"])
    assert (episodes_given.episodes, episodes_given.steps) == (30, DEFAULT_BUDGET[0])
    assert episodes_given.policy_args == SUITE_ARGS
    assert draccus.parse(SuiteBenchConfig, args=["--preset", "gpu"]).steps == 3000
    on_gpu = draccus.parse(SuiteBenchConfig, args=["--device", "cuda"])
    assert (on_gpu.episodes, on_gpu.steps) == (50, DEFAULT_BUDGET[0])


def test_device_option_reaches_lerobot_train_and_the_table(tmp_path):
    gpu = SuiteBenchConfig(tasks=["lift"], device="cuda", output_dir=tmp_path)
    command = gpu.train_run(1, tmp_path / "keyframe").command()
    assert "--policy.device=cuda" in command and "--seed=1" in command
    assert "--num_workers=4" in command  # a GPU run reads its batches in loader workers
    assert f"--output_dir={tmp_path / 'runs' / 'seed1_decay7500_lr0.003' / 'train'}" in command
    assert "--policy.preset=suite" in command and "--policy.use_cpu_bf16_autocast=true" in command
    assert ", CUDA; closed loop" in markdown(gpu, [_result(1, {"lift:lift_cube": 20})])
    scored_here = _result(1, {"lift:lift_cube": 20}) | {"trained_on": "cuda"}  # trained there, reused here
    assert ", trained on CUDA, scored on CPU; closed loop" in markdown(
        SuiteBenchConfig(tasks=["lift"]), [scored_here]
    )
    cpu = SuiteBenchConfig(tasks=["lift"], output_dir=tmp_path)
    cpu_command = cpu.train_run(0, tmp_path / "keyframe").command()
    assert "--policy.device=cpu" in cpu_command and "--num_workers=0" in cpu_command


def test_held_out_error_per_task_when_the_diagnostics_split_it():
    cfg = SuiteBenchConfig(tasks=["lift", "stack", "pick_place"], seeds=[0, 1])
    results = [_result(0, {"lift:lift_cube": 20}), _result(1, {"lift:lift_cube": 20})]
    assert "held-out keyframes, median cm" not in markdown(cfg, results)  # no split recorded: no table
    held = results[0]["diagnostics"]["checkpoints"][0]["heldout"]
    results[0]["diagnostics"]["checkpoints"][0]["heldout"] = held | {
        "per_task": {
            "stack": {"all": {"trans_cm_median": 0.42, "within_1cm": 0.9}},
            "lift": {"all": {"trans_cm_median": 0.22, "within_1cm": 1.0}},
        }
    }
    text = markdown(cfg, results)
    assert "| task: held-out keyframes, median cm (≤ 1 cm) | seed 0 | seed 1 |" in text
    # Tasks in the suite's order; a seed without the split gets a dash; a task nobody measured gets no row.
    assert text.index("| lift | 0.22 (100%) | - |") < text.index("| stack | 0.42 (90%) | - |")
    assert "| pick_place |" not in text


def test_jittered_demonstrations_are_named_and_never_mixed_with_clean_ones(tmp_path):
    """``--pregrasp_jitter_m`` says so in the table's description, and training data on disk collected with another
    jitter is refused rather than reused (the held-out seeds are always the experts' own)."""
    cfg = draccus.parse(SuiteBenchConfig, args=["--pregrasp_jitter_m", "0.02", "--tasks", "[lift]"])
    assert "approach waypoints moved up to 2 cm" in markdown(cfg, [_result(0, {"lift:lift_cube": 20})])
    assert "moved up to" not in markdown(
        SuiteBenchConfig(tasks=["lift"]), [_result(0, {"lift:lift_cube": 20})]
    )
    # Finished collections of the clean experts, recorded as collect.json records them.
    for where, episodes, start in (("train", 2, 0), ("heldout", 1, 50_000)):
        data = tmp_path / where / "data"
        (data / "keyframe" / "meta").mkdir(parents=True)
        (data / "keyframe" / "meta" / "info.json").write_text("{}")
        options = demonstration_config(
            tmp_path / where, ["lift"], episodes, ["agentview"], 32, 1, f"local/t_{where}", dense=False,
            start_seed=start,
        ).data_options()  # fmt: skip
        (data / "collect.json").write_text(json.dumps({"config": options}))
    reused = collect_train_and_heldout(tmp_path, ["lift"], 2, 1, ["agentview"], 32, 1, "t")
    assert reused == (tmp_path / "train" / "data" / "keyframe", tmp_path / "heldout" / "data" / "keyframe")
    with pytest.raises(
        FileExistsError, match=r"train/data was collected with other options \(render\.height 32 -> 48"
    ):
        collect_train_and_heldout(tmp_path, ["lift"], 2, 1, ["agentview"], 48, 1, "t")
    with pytest.raises(FileExistsError, match=r"other options \(pregrasp_jitter_m 0\.0 -> 0\.02\)"):
        collect_train_and_heldout(tmp_path, ["lift"], 2, 1, ["agentview"], 32, 1, "t", pregrasp_jitter_m=0.02)


def test_stop_after_train_trains_every_seed_on_the_collected_data_and_scores_nothing(
    tmp_path, monkeypatch, capsys
):
    """``--stop_after train`` (a GPU machine without robosuite, docs/gpu.md): the datasets found on disk, one run per
    seed, then a summary; no diagnosis or closed loop. An unknown stage is refused."""
    import benchmarks.bench_suite as bench
    import benchmarks.training_runs as runs

    data = (tmp_path / "train" / "data" / "keyframe", tmp_path / "heldout" / "data" / "keyframe")
    monkeypatch.setattr(bench, "collect_data", lambda cfg: data)
    trained = []
    monkeypatch.setattr(runs, "train_unless_done", lambda run, run_dir, label: trained.append(run) or 420.0)
    monkeypatch.setattr(bench, "run_one", lambda *a: pytest.fail("scored a run"))
    assert bench.main(["--output_dir", str(tmp_path), "--seeds", "[0,1]", "--stop_after", "train"]) == 0
    assert [r.seed for r in trained] == [0, 1] and {r.dataset_root for r in trained} == {data[0]}
    out = capsys.readouterr().out
    assert (
        "bench_suite: stopped after train; data " in out
        and "seed 1: " in out
        and "(7.0 min of training)" in out
    )
    trained.clear()
    assert bench.main(["--output_dir", str(tmp_path), "--stop_after", "collect"]) == 0
    assert not trained
    with pytest.raises(ValueError, match="--stop_after must be one of collect, train, evaluate"):
        SuiteBenchConfig(stop_after="score")


def test_the_seeds_scored_as_one_ensemble_get_a_column_and_a_row():
    cfg = SuiteBenchConfig(tasks=["lift", "stack"], seeds=[1, 2], ensemble=True)
    results = [
        _result(1, {"lift:lift_cube": 20, "stack:red_on_green": 6}),
        _result(2, {"lift:lift_cube": 20, "stack:red_on_green": 10}),
    ]
    together = _result(0, {"lift:lift_cube": 20, "stack:red_on_green": 12})["eval"]
    text = markdown(cfg, results, together)
    assert "| variation | seed 1 | seed 2 | the seeds as one ensemble |" in text
    assert "| stack:red_on_green | 6/20 (10–90%) | 10/20 (10–90%) | 12/20 (10–90%) |" in text
    assert "| ensemble of 1, 2 | - | - | - | - | - | **32/40" in text and "dropped 8 | - | 15 |" in text
    assert "the seeds as one ensemble" not in markdown(cfg, results)
    assert cfg.ensemble_dir().name == "ensemble_seeds1-2_decay7500_lr0.003"
    with pytest.raises(ValueError, match="--ensemble needs two training seeds or more"):
        SuiteBenchConfig(seeds=[0], ensemble=True)


def test_the_ensemble_is_scored_with_every_seeds_checkpoint_and_rescored_only_for_other_weights(
    tmp_path, monkeypatch
):
    import benchmarks.bench_suite as bench
    import pipelines.evaluate as evaluate

    cfg = SuiteBenchConfig(tasks=["lift"], seeds=[0, 1], ensemble=True, output_dir=tmp_path)
    train_root = tmp_path / "train" / "data" / "keyframe"
    for seed in cfg.seeds:
        checkpoint = cfg.train_run(seed, train_root).checkpoint
        checkpoint.mkdir(parents=True)
        (checkpoint / "model.safetensors").write_bytes(bytes([seed]))
    scored = []

    def run_eval(eval_cfg):
        scored.append(eval_cfg)
        eval_cfg.output_dir.mkdir(parents=True, exist_ok=True)
        summary = {"variations": [], "seconds": 60.0}
        (eval_cfg.output_dir / "results.json").write_text(json.dumps(summary))
        return summary

    monkeypatch.setattr(evaluate, "run_eval", run_eval)
    bench.evaluate_ensemble(cfg, train_root)
    (first,) = scored
    assert first.checkpoint == cfg.train_run(0, train_root).checkpoint
    assert first.ensemble == [cfg.train_run(1, train_root).checkpoint] and first.train_dataset == train_root
    assert first.output_dir == cfg.ensemble_dir() / "eval" and first.max_keyframes == cfg.max_keyframes
    bench.evaluate_ensemble(cfg, train_root)
    assert len(scored) == 1  # the same weights: their results are reused
    (cfg.train_run(1, train_root).checkpoint / "model.safetensors").write_bytes(b"retrained")
    bench.evaluate_ensemble(cfg, train_root)
    assert len(scored) == 2
