"""The demonstrations benchmark trains on the N lowest seeds of every variation: nested sets, whatever the order
the episodes were merged in."""

from __future__ import annotations

import json

import pytest

from benchmarks.bench_demos import DemosBenchConfig, first_seeds, run_dir, train_run


def _sidecar(root, episodes):
    (root / "meta").mkdir(parents=True)
    (root / "meta" / "sigma.json").write_text(json.dumps({"episodes": episodes}))


def test_first_seeds_per_variation(tmp_path):
    # Shards merged out of seed order: lift 2,0,1 then stack a 1,0 then stack b 0.
    eps = [
        {"episode_index": 0, "task": "lift", "variation": "lift_cube", "seed": 2},
        {"episode_index": 1, "task": "lift", "variation": "lift_cube", "seed": 0},
        {"episode_index": 2, "task": "lift", "variation": "lift_cube", "seed": 1},
        {"episode_index": 3, "task": "stack", "variation": "a", "seed": 1},
        {"episode_index": 4, "task": "stack", "variation": "a", "seed": 0},
        {"episode_index": 5, "task": "stack", "variation": "b", "seed": 0},
    ]
    _sidecar(tmp_path, eps)
    assert first_seeds(tmp_path, 1) == [1, 4, 5]
    assert first_seeds(tmp_path, 2) == [1, 2, 3, 4, 5]
    assert set(first_seeds(tmp_path, 1)) <= set(first_seeds(tmp_path, 2))
    assert first_seeds(tmp_path, 10) == list(range(6))


def test_first_seeds_needs_seeds(tmp_path):
    _sidecar(tmp_path, [])
    with pytest.raises(ValueError, match=r"sigma\.json"):
        first_seeds(tmp_path, 1)


def test_train_run_passes_policy_args_and_the_nested_episodes(tmp_path):
    eps = [
        {"episode_index": i, "task": "pick_place", "variation": v, "seed": s}
        for i, (v, s) in enumerate([("milk", 0), ("milk", 1), ("can", 0), ("can", 1)])
    ]
    _sidecar(tmp_path, eps)
    cfg = DemosBenchConfig(
        output_dir=tmp_path / "out",
        tasks=["pick_place"],
        seed=1,
        policy_args=["--policy.per_task_bounds=true"],
    )
    run = train_run(cfg, 1, tmp_path, first_seeds(tmp_path, 1))
    assert run.extra_args == ["--policy.per_task_bounds=true", "--dataset.episodes=[0,2]"]
    assert "--policy.per_task_bounds=true" in run.arguments()
    # A second training seed gets its own run directory; seed 0 keeps the published one's name.
    assert run.output_dir == tmp_path / "out" / "runs" / "demos_1_seed1" / "train"
    assert run_dir(DemosBenchConfig(output_dir=tmp_path), 30) == tmp_path / "runs" / "demos_30"
