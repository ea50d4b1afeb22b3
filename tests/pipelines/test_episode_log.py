"""``pipelines/episode_log.py``: a killed ``sigma-eval`` resumes from the episodes it logged, and only under the
same weights and options.

The bookkeeping is tested here with the episode itself stood in for (``run_job``): the robosuite rollouts are
tested by the demo's quick run (tests/pipelines/test_demo.py), which evaluates from scratch through the same code.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

import pipelines.evaluate as evaluate
from pipelines.checkpoints import CheckpointError
from pipelines.episode_log import LOG_NAME, EpisodeLog
from pipelines.evaluate import EvalConfig, run_eval
from pipelines.rollout import EpisodeResult, Job
from tests.pipelines.checkpoint_fixtures import save_tiny_checkpoint
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


def _episode(seed: int, success: bool = True) -> EpisodeResult:
    return EpisodeResult("lift", "lift_cube", seed, success, 3, 120, 1.5)


def test_a_log_cut_short_by_a_kill_resumes_its_whole_lines(tmp_path: Path, caplog) -> None:
    log = EpisodeLog(tmp_path, {"weights_sha256": "abc", "max_keyframes": 4})
    assert log.resume(lambda d: EpisodeResult(**d)) == []
    log.append(_episode(1))
    log.append(_episode(2, success=False))
    with open(log.path, "a") as f:
        f.write('{"task": "lift", "variat')  # the kill came mid-line
    again = EpisodeLog(tmp_path, {"weights_sha256": "abc", "max_keyframes": 4})
    assert again.resume(lambda d: EpisodeResult(**d)) == [_episode(1), _episode(2, success=False)]
    assert f"{LOG_NAME}:4: skipped" in caplog.text
    lines = again.path.read_text().splitlines()
    assert len(lines) == 3  # the header and the two episodes; the torn line is gone


def test_a_log_of_other_weights_or_options_is_not_trusted(tmp_path: Path, caplog) -> None:
    log = EpisodeLog(tmp_path, {"weights_sha256": "abc", "max_keyframes": 4})
    log.resume(lambda d: EpisodeResult(**d))
    log.append(_episode(1))
    other = EpisodeLog(tmp_path, {"weights_sha256": "abc", "max_keyframes": 8})
    assert other.resume(lambda d: EpisodeResult(**d)) == []
    assert "written under other weights or options" in caplog.text
    assert json.loads(other.path.read_text().splitlines()[0])["max_keyframes"] == 8


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    root = write_tiny_keyframe_dataset(tmp_path_factory.mktemp("data") / "tiny", episodes=2, size=32)
    out = tmp_path_factory.mktemp("ckpt") / "pretrained_model"
    save_tiny_checkpoint(root, out, [0, 1], seed=0)
    return out


def test_a_killed_evaluation_plays_only_the_missing_episodes(checkpoint: Path, tmp_path: Path, monkeypatch):
    played: list[int] = []

    def play(job: Job) -> EpisodeResult:
        if job.seed == kill_at:
            raise KeyboardInterrupt  # the run is killed while this episode plays
        played.append(job.seed)
        return _episode(job.seed, success=job.seed % 2 == 0)

    monkeypatch.setattr(evaluate, "init_worker", lambda cfg: None)
    monkeypatch.setattr(evaluate, "run_job", play)
    cfg = EvalConfig(checkpoint=checkpoint, tasks=["lift"], episodes=4, workers=1, output_dir=tmp_path)
    (tmp_path / "results.json").write_text("{}")  # an earlier run's: not to be taken for this one's
    kill_at = 100_002
    with pytest.raises(KeyboardInterrupt):
        run_eval(cfg)
    assert played == [100_000, 100_001] and not (tmp_path / "results.json").exists()

    kill_at, played[:] = None, []
    summary = run_eval(cfg)
    assert played == [100_002, 100_003] and summary["resumed_episodes"] == 2
    assert summary["variations"][0]["successes"] == 2 and summary["variations"][0]["episodes"] == 4
    assert (tmp_path / "results.json").exists() and not (tmp_path / LOG_NAME).exists()

    played[:] = []
    run_eval(cfg)  # a finished evaluation is redone
    assert played == [100_000, 100_001, 100_002, 100_003]

    kill_at, played[:] = 100_001, []
    with pytest.raises(KeyboardInterrupt):
        run_eval(cfg)
    kill_at, played[:] = None, []
    cfg.max_keyframes = 5  # another keyframe budget: the logged episode is not this evaluation's
    assert run_eval(cfg)["resumed_episodes"] == 0 and played == [100_000, 100_001, 100_002, 100_003]


def test_ensemble_members_are_checked_first_and_their_weights_decide_what_a_log_is_trusted_for(
    checkpoint: Path, tmp_path: Path, monkeypatch
):
    played: list[int] = []

    def play(job: Job) -> EpisodeResult:
        if job.seed == kill_at:
            raise KeyboardInterrupt
        played.append(job.seed)
        return _episode(job.seed)

    monkeypatch.setattr(evaluate, "init_worker", lambda cfg: None)
    monkeypatch.setattr(evaluate, "run_job", play)
    out = tmp_path / "eval"
    cfg = EvalConfig(checkpoint=checkpoint, tasks=["lift"], episodes=3, workers=1, output_dir=out)
    cfg.ensemble = [tmp_path / "missing"]
    with pytest.raises(CheckpointError, match=r"--ensemble: .*missing is not a pretrained_model"):
        run_eval(cfg)
    wider = tmp_path / "wider"
    shutil.copytree(checkpoint, wider)
    config = json.loads((wider / "config.json").read_text())
    (wider / "config.json").write_text(json.dumps(config | {"img_size": 64}))
    cfg.ensemble = [wider]
    with pytest.raises(ValueError, match=r"member .*wider: img_size is 64, the first policy's is 32"):
        run_eval(cfg)
    assert not played  # refused before any episode

    cfg.ensemble, kill_at = [], 100_001
    with pytest.raises(KeyboardInterrupt):
        run_eval(cfg)  # the single policy's evaluation, killed after one episode
    cfg.ensemble, kill_at, played[:] = [checkpoint], None, []
    summary = run_eval(cfg)  # the ensemble is not that policy: its episode is played again
    assert summary["resumed_episodes"] == 0 and played == [100_000, 100_001, 100_002]
    assert summary["config"]["ensemble"] == [str(checkpoint)]
