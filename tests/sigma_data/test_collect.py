"""End-to-end collection: 2 Lift episodes with the real expert, small images, both datasets read back by stock
LeRobotDataset; determinism and resume after an interrupted shard; a damaged finished shard is redone, not
reused; clear errors on bad names."""

import importlib.util
import json
import logging
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import draccus
import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from sigma_data.cameras import RenderOptions
from sigma_data.cli import main as cli_main
from sigma_data.collect import (
    MARKER,
    CollectConfig,
    CollectOutputConfig,
    check_shard,
    collect,
    merge_shards,
)
from sigma_data.collect import envs as collect_envs
from sigma_data.collect.config import recorded_options
from sigma_data.contract import read_sidecar
from sigma_data.suite import get_task
from sigma_data.validate import ValidateConfig, validate_dataset


def tiny(out, cameras: str = "agentview,robot0_eye_in_hand", size: int = 32, **output) -> CollectConfig:
    """Two Lift seeds, one per shard, into ``out``; ``output`` are further ``--output.*`` options."""
    return CollectConfig(
        tasks="lift",
        episodes=2,
        shard_size=1,
        render=RenderOptions(cameras=cameras, height=size, width=size),
        output=CollectOutputConfig(dir=out, **output),
        progress=False,
    )


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("collect")
    return out, collect(tiny(out))


def columns(root, names):
    ds = LeRobotDataset("local/x", root=root, depth_output_unit="m", video_backend="pyav")
    return ds, {k: np.asarray(v) for k, v in ds.hf_dataset.with_format(None).select_columns(names)[:].items()}


def test_tiny_collection_reads_back(first_run):
    out, summary = first_run
    assert summary.kept == 2 and summary.dropped == 0
    assert set(summary.outputs) == {"dense", "keyframe"}
    dense, _cols = columns(out / "dense", ["sigma.next_keyframe_index", "episode_index"])
    assert dense.meta.total_episodes == 2 and len(dense) == summary.frames("dense")
    assert "sigma.is_keyframe" in dense.meta.features and dense.meta.depth_keys
    item = dense[0]
    assert item["observation.images.agentview"].shape == (3, 32, 32)
    assert item["observation.images.agentview_depth"].shape == (1, 32, 32)
    assert item["task"] == "lift the cube"
    keyframe = LeRobotDataset("local/y", root=out / "keyframe", depth_output_unit="m", video_backend="pyav")
    assert keyframe.meta.total_episodes == 2 and keyframe.meta.features["action"]["shape"] == (9,)
    assert keyframe[1]["action"].shape == (9,)
    for kind in ("dense", "keyframe"):
        report = validate_dataset(ValidateConfig(root=out / kind, frames_per_episode=2))
        assert report.num_errors == 0, report.table()
    side = read_sidecar(out / "keyframe")
    assert [e["seed"] for e in side["episodes"]] == [0, 1]
    assert side["bounds"]["lift"] == list(get_task("lift").bounds)
    assert side["static_calibration"]["lift"]["agentview"]["extrinsics"]
    assert "heuristic_keyframes" in side["episodes"][0]["provenance"]


def test_rerun_skips_finished_shards_and_resumes_an_interrupted_one(first_run, tmp_path):
    out, summary = first_run
    resumed = tmp_path / "resumed"
    shutil.copytree(out / "shards", resumed / "shards")
    shutil.copy(out / "collect.json", resumed / "collect.json")  # written before the first shard starts
    # An interrupted shard: killed before its marker, its dataset never finalized.
    second = resumed / "shards" / summary.shards[1].name
    (second / MARKER).unlink()
    shutil.rmtree(second / "dense" / "meta" / "episodes")
    again = collect(tiny(resumed))
    assert [s.skipped for s in again.shards] == [True, False]
    # Same seeds give identical data (the redone shard and the merged datasets).
    for kind, names in (
        (
            "dense",
            [
                "observation.state",
                "action",
                "sigma.next_keyframe_index",
                "observation.camera.robot0_eye_in_hand.extrinsics",
            ],
        ),
        ("keyframe", ["observation.state", "action", "sigma.source_frame"]),
    ):
        _, a = columns(out / kind, names)
        _, b = columns(resumed / kind, names)
        for name in names:
            np.testing.assert_array_equal(a[name], b[name], err_msg=f"{kind} {name}")
    ka = LeRobotDataset("local/a", root=out / "keyframe", depth_output_unit="m", video_backend="pyav")
    kb = LeRobotDataset("local/b", root=resumed / "keyframe", depth_output_unit="m", video_backend="pyav")
    last = len(ka) - 1
    for key in ("observation.images.agentview", "observation.images.robot0_eye_in_hand_depth"):
        np.testing.assert_array_equal(ka[last][key].numpy(), kb[last][key].numpy())


def _copy_run(out, dest):
    """A rerun's starting point: the shards and the record of a finished run (its merged datasets left out)."""
    shutil.copytree(out / "shards", dest / "shards")
    shutil.copy(out / "collect.json", dest / "collect.json")
    return dest


def _truncate(path, keep: float) -> None:
    with path.open("r+b") as f:
        f.truncate(int(path.stat().st_size * keep))


def test_a_shard_with_a_truncated_video_is_redone_not_reused(first_run, tmp_path, caplog):
    """A finished shard whose video was cut short (metadata intact) is redone, the run says which and why, and
    every frame of the merged dense dataset decodes."""
    out, summary = first_run
    damaged = _copy_run(out, tmp_path / "damaged")
    first = damaged / "shards" / summary.shards[0].name
    video = sorted((first / "dense" / "videos").rglob("*.mp4"))[0]
    _truncate(video, keep=0.5)
    why = f"{video.relative_to(first).as_posix()} has {video.stat().st_size} bytes, "
    with caplog.at_level(logging.WARNING, logger="sigma_data.collect"):
        again = collect(tiny(damaged))
    assert [s.skipped for s in again.shards] == [False, True]
    assert again.shards[0].redone.startswith(why) and "when the shard finished" in again.shards[0].redone
    assert f"redoing shard {summary.shards[0].name}: {again.shards[0].redone}" in caplog.text
    assert not again.shards[1].redone and "2 shards (1 reused, 1 redone)" in again.line()
    assert check_shard(first, tiny(damaged))[0] is not None  # the redone shard verifies
    dense = LeRobotDataset("local/d", root=damaged / "dense", video_backend="pyav")
    assert len(dense) == summary.frames("dense")
    for i in range(len(dense)):  # every frame of every camera stream decodes
        assert dense[i]["observation.images.agentview"].shape == (3, 32, 32)


def test_a_truncated_parquet_and_a_marker_without_files_are_redone(first_run, tmp_path, caplog):
    """A shard whose data parquet was cut short, and one whose marker predates the file list (unverifiable), are
    both redone; the rerun succeeds with the same data."""
    out, summary = first_run
    damaged = _copy_run(out, tmp_path / "damaged")
    first, second = (damaged / "shards" / s.name for s in summary.shards)
    _truncate(first / "keyframe" / "data" / "chunk-000" / "file-000.parquet", keep=0.9)
    old = json.loads((second / MARKER).read_text())
    del old["files"], old["redone"]  # as markers were written before they listed files
    (second / MARKER).write_text(json.dumps(old))
    with caplog.at_level(logging.WARNING, logger="sigma_data.collect"):
        again = collect(tiny(damaged))
    assert [s.skipped for s in again.shards] == [False, False]
    assert again.shards[0].redone.startswith("keyframe/data/chunk-000/file-000.parquet has ")
    assert "lists no files" in again.shards[1].redone
    for spec, shard in zip(summary.shards, again.shards, strict=True):
        assert f"redoing shard {spec.name}: {shard.redone}" in caplog.text
    names = ["observation.state", "action", "sigma.source_frame"]
    _, a = columns(out / "keyframe", names)
    _, b = columns(damaged / "keyframe", names)
    for name in names:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_check_shard_says_what_is_wrong(first_run, tmp_path):
    """Each way a finished shard can differ from what its marker recorded is found, before LeRobot reads it."""
    out, summary = first_run
    cfg = tiny(tmp_path)
    source = out / "shards" / summary.shards[0].name

    def shard(edit=None, marker=None):
        path = tmp_path / f"s{len(list(tmp_path.iterdir()))}"
        shutil.copytree(source, path)
        if edit:
            edit(path)
        if marker:
            stored = json.loads((path / MARKER).read_text())
            marker(stored)
            (path / MARKER).write_text(json.dumps(stored))
        result, why = check_shard(path, cfg)
        assert (result is None) == bool(why)
        return why

    def flip_a_byte(path):  # same size, same footer: only the hash sees it
        data = path / "keyframe" / "data" / "chunk-000" / "file-000.parquet"
        raw = bytearray(data.read_bytes())
        raw[len(raw) // 2] ^= 0xFF
        data.write_bytes(bytes(raw))

    def rows(stored):
        next(e for e in stored["files"]["keyframe"] if "rows" in e)["rows"] += 1

    assert shard() == ""
    assert (
        shard(flip_a_byte)
        == "keyframe/data/chunk-000/file-000.parquet differs from the file the shard wrote (SHA-256)"
    )
    assert shard(lambda p: (p / "dense" / "meta" / "info.json").unlink()) == "dense/meta/info.json is missing"
    assert " rows, " in shard(marker=rows) and "when the shard finished" in shard(marker=rows)
    assert "the shard wrote 1 frames" in shard(marker=lambda m: m["frames"].update(keyframe=1))
    assert "lists no files" in shard(marker=lambda m: m.pop("files"))
    assert "other options" in shard(marker=lambda m: m.update(fingerprint="0"))
    assert "interrupted" in shard(lambda p: (p / MARKER).unlink())
    assert check_shard(tmp_path / "absent", cfg) == (None, "")


def test_a_merge_error_names_the_damaged_shard(first_run, tmp_path):
    out, summary = first_run
    copy = _copy_run(out, tmp_path / "copy")
    bad = copy / "shards" / summary.shards[1].name
    _truncate(bad / "keyframe" / "data" / "chunk-000" / "file-000.parquet", keep=0.9)
    roots = [copy / "shards" / s.name / "keyframe" for s in summary.shards]
    with pytest.raises(RuntimeError, match="damaged shard") as err:
        merge_shards("keyframe", roots, tmp_path / "merged", "local/merged")
    assert f"{bad} (keyframe/data/chunk-000/file-000.parquet has " in str(err.value)
    assert str(copy / "shards" / summary.shards[0].name) + " (" not in str(err.value)
    assert not (tmp_path / "merged").exists()


def test_existing_data_is_never_replaced_without_overwrite(first_run, tmp_path, capsys):
    """A directory of other files, or a finished collection made with other options, is an error that touches
    nothing; ``--overwrite=true`` replaces it; a merge swaps the finished dataset in (no partial one at the path)."""
    mine = tmp_path / "mine"
    (mine / "dense").mkdir(parents=True)
    (mine / "dense" / "f.txt").write_text("keep")
    with pytest.raises(FileExistsError, match=r"holds no collect\.json"):
        collect(tiny(mine))
    assert (mine / "dense" / "f.txt").read_text() == "keep" and sorted(p.name for p in mine.iterdir()) == [
        "dense"
    ]

    out, _ = first_run
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    code = cli_main(["collect", *_args(replace(tiny(out, size=48), episodes=1))])
    assert code != 0
    err = capsys.readouterr().err
    assert "other options (episodes 2 -> 1, render.height 32 -> 48, render.width 32 -> 48)" in err
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before  # nothing touched
    # Changing only how it runs resumes: every shard reused, the merged datasets swapped in whole.
    again = collect(replace(tiny(out), render_threads=1))
    assert all(s.skipped for s in again.shards)
    assert not list(out.glob(".*merging")) and not list(out.glob(".*replaced"))

    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    one = collect(replace(tiny(copy, overwrite=True), episodes=1))
    assert (
        one.kept == 1
        and LeRobotDataset("local/c", root=copy / "dense", video_backend="pyav").num_episodes == 1
    )


# tiny()'s options as collect.json recorded them before the render and output options were grouped under
# --render.* and --output.* (flat names; what the flat CollectConfig's data_options() gave).
OLD_RECORD = {
    "tasks": "lift",
    "variations": "all",
    "episodes": "2",
    "start_seed": "0",
    "repo_id": "local/sigma",
    "cameras": "agentview,robot0_eye_in_hand",
    "height": "32",
    "width": "32",
    "dense": "True",
    "keyframe": "True",
    "dense_depth": "True",
    "dense_video": "True",
    "keyframe_video": "False",
    "augment_every": "0",
    "fast_render": "True",
    "max_depth": "3.0",
    "shard_size": "1",
    "model_seed": "0",
}


def test_a_jittered_collection_moves_the_approach_and_is_kept_apart(first_run, tmp_path):
    """``--pregrasp_jitter_m`` reaches the experts: each episode's first keyframe action (the approach) is off its
    second (the grasp) sideways, where the experts' own are straight above; the shards are fingerprinted apart and a
    collection made without it is not resumed with it."""
    out, _ = first_run
    jittered = replace(tiny(tmp_path / "dart", dense=False), pregrasp_jitter_m=0.02)
    assert jittered.fingerprint() != tiny(tmp_path / "dart", dense=False).fingerprint()
    assert collect(jittered).kept == 2

    def sideways(root: Path) -> list[float]:
        ds = LeRobotDataset("local/y", root=root, depth_output_unit="m", video_backend="pyav")
        actions = np.stack([ds.hf_dataset[i]["action"] for i in range(len(ds))])
        starts = [i for i in range(len(ds)) if int(ds.hf_dataset[i]["frame_index"]) == 0]
        return [float(np.linalg.norm(actions[i, :2] - actions[i + 1, :2])) for i in starts]

    assert all(d < 0.003 for d in sideways(out / "keyframe"))
    assert all(0.002 < d < 0.025 for d in sideways(tmp_path / "dart" / "keyframe"))
    assert read_sidecar(tmp_path / "dart" / "keyframe")["pregrasp_jitter_m"] == 0.02
    assert read_sidecar(out / "keyframe")["pregrasp_jitter_m"] == 0.0
    with pytest.raises(FileExistsError, match=r"pregrasp_jitter_m 0\.0 -> 0\.02"):
        collect(replace(tiny(out), pregrasp_jitter_m=0.02))
    with pytest.raises(ValueError, match="pregrasp_jitter_m"):
        CollectConfig(pregrasp_jitter_m=-0.01)


def test_grouped_options_keep_the_fingerprint_and_read_old_records(tmp_path):
    """Shards written before the options were grouped keep matching: the fingerprints below were computed with
    the flat CollectConfig; an old collect.json's names map onto today's."""
    assert CollectConfig().fingerprint() == "30aecf5f1d7572ea"
    small = CollectConfig(render=RenderOptions(height=64, width=64), output=CollectOutputConfig(dense=False))
    assert small.fingerprint() == "04f8d5a39ba02d3f"
    other = CollectConfig(
        render=RenderOptions(cameras="agentview,frontview", fast=False, max_depth=2.5),
        output=CollectOutputConfig(augment_every=3),
        model_seed=7,
    )
    assert other.fingerprint() == "5bc3e9ded696d97f"
    cfg = tiny(tmp_path)
    assert cfg.fingerprint() == "f1966cf0f0b21e97"
    # How a run goes (where, with how many workers...) is neither fingerprinted nor compared between runs.
    run = replace(cfg, output=replace(cfg.output, dir=tmp_path / "elsewhere", overwrite=True), workers=3)
    assert run.fingerprint() == cfg.fingerprint() and run.data_options() == cfg.data_options()
    mine = cfg.data_options()
    assert mine["render.height"] == "32" and mine["output.dense"] == "True" and "output.dir" not in mine
    # An option added since (pregrasp_jitter_m) is absent from the old record; resuming reads it as its default.
    assert recorded_options(OLD_RECORD) | {"pregrasp_jitter_m": "0.0"} == mine
    assert recorded_options(mine) == mine


def test_an_output_option_on_the_command_line_keeps_collects_output_defaults():
    """draccus builds a sub-config from its class's defaults once one of its options is given: collect's own
    defaults (its own class) stay, so a rerun with ``--output.dense=false`` still has the repo_id it recorded."""
    cfg = draccus.parse(CollectConfig, args=["--output.dense=false", "--render.height=64"])
    assert cfg.output == CollectOutputConfig(dense=False) and cfg.render == RenderOptions(height=64)
    assert (cfg.output.dir, cfg.output.repo_id) == (Path("outputs/sigma_data"), "local/sigma")
    assert cfg.fingerprint() == replace(cfg, output=CollectOutputConfig(dense=False)).fingerprint()


def _with_old_record(run):
    record = json.loads((run / "collect.json").read_text())
    record["config"] = dict(OLD_RECORD)
    (run / "collect.json").write_text(json.dumps(record, indent=1))
    return run


def test_a_collection_recorded_with_the_old_option_names_resumes(first_run, tmp_path):
    """A collection whose collect.json has the flat option names of before resumes: every shard reused, the record
    rewritten with today's names; other options than it records are still refused, named by today's names."""
    out, summary = first_run
    old = _with_old_record(_copy_run(out, tmp_path / "old"))
    again = collect(tiny(old))
    assert all(s.skipped for s in again.shards) and again.kept == summary.kept
    assert json.loads((old / "collect.json").read_text())["config"] == tiny(old).data_options()
    other = _with_old_record(_copy_run(out, tmp_path / "other"))
    with pytest.raises(
        FileExistsError, match=r"other options \(render\.height 32 -> 48, render\.width 32 -> 48\)"
    ):
        collect(tiny(other, size=48))


def _args(cfg: CollectConfig) -> list[str]:
    return [
        f"--tasks={cfg.tasks}",
        f"--episodes={cfg.episodes}",
        f"--shard_size={cfg.shard_size}",
        f"--render.cameras={cfg.render.cameras}",
        f"--render.height={cfg.render.height}",
        f"--render.width={cfg.render.width}",
        f"--output.dir={cfg.output.dir}",
        "--progress=false",
    ]


def test_two_workers_share_the_shards_and_give_the_same_data(first_run, tmp_path):
    """workers=2: this process and one spawned helper each collect a shard; the data equal the 1-worker run."""
    out, summary = first_run
    two = collect(replace(tiny(tmp_path / "two"), workers=2))
    assert two.kept == 2 and [s.name for s in two.shards] == [s.name for s in summary.shards]
    names = ["observation.state", "action", "sigma.source_frame"]
    _, a = columns(out / "keyframe", names)
    _, b = columns(tmp_path / "two" / "keyframe", names)
    for name in names:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    with pytest.raises(ValueError, match=r"unknown camera\(s\) \['nocam'\]"):
        collect(replace(tiny(tmp_path / "bad", cameras="agentview,nocam"), workers=2))
    assert not (tmp_path / "bad").exists()  # a rejected run leaves no collect.json or empty shards/ behind


def test_single_shard_is_copied_and_reads_back(tmp_path):
    """One shard is the merged dataset already (copied, not re-aggregated); the process's envs are closed after."""
    summary = collect(replace(tiny(tmp_path, dense=False), episodes=1))
    assert len(summary.shards) == 1 and summary.kept == 1 and set(summary.outputs) == {"keyframe"}
    ds, cols = columns(tmp_path / "keyframe", ["episode_index", "action"])
    assert ds.meta.total_episodes == 1 and len(ds) == summary.frames("keyframe") == len(cols["action"])
    assert ds[0]["observation.images.agentview"].shape == (3, 32, 32)
    report = validate_dataset(ValidateConfig(root=tmp_path / "keyframe", frames_per_episode=2))
    assert report.num_errors == 0, report.table()
    side = read_sidecar(tmp_path / "keyframe")
    assert side["num_episodes"] == 1 and side["episodes"][0]["shard"] == summary.shards[0].name
    assert not collect_envs._ENVS


def test_bad_names_give_clear_errors(tmp_path):
    with pytest.raises(ValueError, match=r"unknown task .lfit.*known tasks"):
        collect(replace(tiny(tmp_path), tasks="lfit"))
    with pytest.raises(ValueError, match="unknown variation"):
        collect(replace(tiny(tmp_path), variations="red_on_green"))
    with pytest.raises(ValueError, match=r"unknown camera\(s\) \['nocam'\] for task 'lift'"):
        collect(tiny(tmp_path, cameras="agentview,nocam"))
    assert cli_main(["collect", "--tasks=lfit", f"--output.dir={tmp_path}"]) == 1
    assert cli_main(["frobnicate"]) == 2
    with pytest.raises(ValueError, match="render_threads"):
        replace(tiny(tmp_path), render_threads=-1)


def test_render_threads_share_the_cores_among_workers(tmp_path):
    cores = len(os.sched_getaffinity(0))
    assert replace(tiny(tmp_path), render_threads=3, workers=2).threads_per_worker() == 3
    assert replace(tiny(tmp_path), workers=1).threads_per_worker() == cores
    assert replace(tiny(tmp_path), workers=2 * cores).threads_per_worker() == 1


@pytest.mark.skipif(importlib.util.find_spec("datatrove") is None, reason="optional dependency datatrove")
def test_datatrove_local_executor(first_run, tmp_path):
    out, _ = first_run
    summary = collect(replace(tiny(tmp_path / "dt"), executor="datatrove"))
    assert summary.kept == 2
    _, a = columns(out / "keyframe", ["action"])
    _, b = columns(tmp_path / "dt" / "keyframe", ["action"])
    np.testing.assert_array_equal(a["action"], b["action"])


def test_cli_output_is_the_summary_line_only(tmp_path):
    """A dense collection with videos from the command line: no video-encoder chatter (SVT-AV1 printed ~25 lines
    per video and FFmpeg's muxer one per file), only the summary line. A fresh process: SVT reads its log level
    once per process."""
    env = {k: v for k, v in os.environ.items() if k != "SVT_LOG"}
    proc = subprocess.run(
        [sys.executable, "-m", "sigma_data.cli", "collect", "--tasks=lift", "--episodes=1", "--render.height=32",
         "--render.width=32", "--render.cameras=agentview", f"--output.dir={tmp_path}", "--progress=false"],
        capture_output=True, text=True, env=env, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = [line for line in (proc.stdout + proc.stderr).splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("collect: kept 1"), lines[:20]


def test_merge_prints_no_per_file_bars(first_run, tmp_path, capfd):
    """LeRobot's SuppressProgressBars turns datasets' bars back on as it exits; a merge keeps them off (and
    LeRobot's own merge bars too without progress)."""
    from datasets.utils.logging import enable_progress_bar

    out, summary = first_run
    enable_progress_bar()  # as LeRobot leaves them after any metadata read
    roots = [out / "shards" / s.name / "keyframe" for s in summary.shards]
    merge_shards("keyframe", roots, tmp_path / "merged", "local/merged")
    err = capfd.readouterr().err
    assert "Copy data and videos" in err  # LeRobot's one bar for the merge stays
    assert "Generating train split" not in err and "Map" not in err, err[-2000:]
    # --progress=false: LeRobot's merge bars too
    merge_shards("keyframe", roots, tmp_path / "quiet", "local/quiet", progress=False)
    err = capfd.readouterr().err
    assert "Copy data and videos" not in err and "Validate all meta data" not in err, err[-2000:]


def test_recording_ahead_keeps_order_raises_and_stops_with_its_consumer():
    from sigma_data.collect.shard import _ahead

    assert list(_ahead(iter(range(5)))) == [0, 1, 2, 3, 4]

    def failing():
        yield 1
        raise ValueError("expert crashed")

    items = _ahead(failing())
    assert next(items) == 1
    with pytest.raises(ValueError, match="expert crashed"):
        next(items)

    produced = []

    def many():
        for i in range(100):
            produced.append(i)
            yield i

    items = _ahead(many(), depth=1)
    assert next(items) == 0
    items.close()  # the consumer stops (e.g. a writer failed): the producer ends after its current item
    assert len(produced) <= 3
