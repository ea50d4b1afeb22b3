"""sigma-diff: paired counts, the exact McNemar test, Newcombe's paired interval, and the CLI on sigma-eval files."""

from __future__ import annotations

import json
import math

import pytest

from pipelines.evaluate import EvalConfig, summarise
from pipelines.paired import (
    Pairs,
    compare,
    load_outcomes,
    load_pooled,
    main,
    mcnemar_exact_p,
    pair_counts,
    paired_difference_interval,
)
from pipelines.rollout import EpisodeResult


def test_pair_counts():
    pairs = pair_counts([True, True, False, False, True], [True, False, True, False, True])
    assert pairs == Pairs(both=2, won=1, lost=1, neither=1)
    assert (pairs.n, pairs.baseline_successes, pairs.candidate_successes) == (5, 3, 3)
    with pytest.raises(ValueError, match="equal length"):
        pair_counts([True], [True, False])


@pytest.mark.parametrize(
    ("won", "lost", "p"),
    [
        (9, 1, 2 * (1 + 10) / 2**10),  # 0.0215
        (6, 2, 2 * (1 + 8 + 28) / 2**8),  # 0.289
        (1, 9, 2 * (1 + 10) / 2**10),  # two-sided: the order does not matter
        (5, 5, 1.0),
        (0, 0, 1.0),
        (0, 6, 2 / 2**6),
    ],
)
def test_mcnemar_exact_p(won, lost, p):
    assert mcnemar_exact_p(won, lost) == pytest.approx(p)


def test_paired_interval_agrees_with_the_normal_approximation_on_many_pairs():
    """On 1000 pairs the paired difference's standard error is sqrt((b + c)/n^2 - (b - c)^2/n^3); Newcombe's
    score interval must be close to the Wald interval there (and is not where the pairing is ignored)."""
    pairs = Pairs(both=400, won=60, lost=40, neither=500)
    diff, lo, hi = paired_difference_interval(pairs)
    n, b, c = 1000, 60, 40
    se = math.sqrt((b + c) / n**2 - (b - c) ** 2 / n**3)
    assert diff == pytest.approx(0.02)
    assert lo == pytest.approx(diff - 1.96 * se, abs=0.002)
    assert hi == pytest.approx(diff + 1.96 * se, abs=0.002)
    unpaired_half_width = 1.96 * math.sqrt(0.46 * 0.54 / n + 0.44 * 0.56 / n)
    assert hi - lo < unpaired_half_width  # pairing: less than half the unpaired interval


def test_paired_interval_properties():
    pairs = Pairs(both=20, won=9, lost=1, neither=130)
    diff, lo, hi = paired_difference_interval(pairs)
    assert lo < diff < hi and lo > 0  # 9 won against 1 lost in 160: significant, as the McNemar test says
    swapped = paired_difference_interval(Pairs(both=20, won=1, lost=9, neither=130))
    assert swapped == pytest.approx((-diff, -hi, -lo))
    same = paired_difference_interval(Pairs(both=12, won=0, lost=0, neither=8))
    assert same[0] == 0.0 and same[1] <= 0.0 <= same[2]
    everything = paired_difference_interval(Pairs(both=0, won=20, lost=0, neither=0))  # an empty margin
    assert everything[0] == 1.0 and -1.0 <= everything[1] < 1.0 and everything[2] == 1.0
    with pytest.raises(ValueError, match="no paired episodes"):
        paired_difference_interval(Pairs(0, 0, 0, 0))


def _results_file(path, outcomes: dict[tuple[str, str, int], str | None]):
    """A results.json written by sigma-eval's own summarise: None is a success, a string the failure reason."""
    results = [
        EpisodeResult(task, variation, seed, failure is None, 3, 100, 1.0, failure=failure)
        for (task, variation, seed), failure in outcomes.items()
    ]
    path.mkdir(parents=True)
    (path / "results.json").write_text(json.dumps(summarise(results, EvalConfig(output_dir=path))))
    return path


def test_compare_and_cli_on_sigma_eval_results(tmp_path, capsys):
    missed, wrong = "grasp missed at keyframe 3", "wrong object: did red_on_green"
    base = _results_file(
        tmp_path / "base",
        {
            ("lift", "lift_cube", 100000): None,
            ("lift", "lift_cube", 100001): missed,
            ("stack", "green_on_red", 100000): wrong,
            ("stack", "green_on_red", 100001): wrong,
            ("stack", "green_on_red", 100002): None,  # not in the candidate: left out
        },
    )
    cand = _results_file(
        tmp_path / "cand",
        {
            ("lift", "lift_cube", 100000): None,
            ("lift", "lift_cube", 100001): None,
            ("stack", "green_on_red", 100000): None,
            ("stack", "green_on_red", 100001): missed,
        },
    )
    result = compare(load_outcomes(base)[1], load_outcomes(cand / "results.json")[1])
    lift, stack = result["variations"]
    assert (lift["won"], lift["lost"], lift["candidate_successes"]) == (1, 0, 2)
    assert (stack["won"], stack["lost"], stack["baseline_successes"]) == (1, 0, 0)
    assert result["all"]["episodes"] == 4 and result["all"]["difference"] == pytest.approx(0.5)
    assert result["failures"] == {
        "baseline": {"wrong object": 2, "grasp missed": 1},
        "candidate": {"grasp missed": 1},
    }
    assert (result["only_baseline"], result["only_candidate"]) == (1, 0)

    out_json = tmp_path / "diff.json"
    assert main(["--baseline", str(base), "--candidate", str(cand), "--output_json", str(out_json)]) == 0
    printed = capsys.readouterr().out
    assert "| **all** |  | 4 | 1 | 3 | 2 / 0 |" in printed
    assert "baseline failures: wrong object 2, grasp missed 1" in printed
    summary = printed.strip().splitlines()[-1]
    assert summary.startswith("sigma-diff: 3/4 against 1/4 on shared episodes, 2 won / 0 lost")
    assert "1 episodes in only one run were left out" in printed
    assert json.loads(out_json.read_text())["all"]["won"] == 2


def test_failures_without_a_recorded_reason(tmp_path):
    """An error is an error; a failure from a results.json older than sigma-eval's reasons is not called one."""
    base = _results_file(tmp_path / "base", {("lift", "lift_cube", 0): "x", ("lift", "lift_cube", 1): "x"})
    data = json.loads((base / "results.json").read_text())
    data["episodes"][0].update(failure=None, error="RuntimeError('sim')")
    data["episodes"][1].update(failure=None)
    (base / "results.json").write_text(json.dumps(data))
    result = compare(load_outcomes(base)[1], load_outcomes(base)[1])
    assert result["failures"]["baseline"] == {"error": 1, "no reason recorded": 1}


def test_evaluations_on_disjoint_seeds_are_pooled(tmp_path, capsys):
    first = _results_file(tmp_path / "a1", {("lift", "lift_cube", 0): None, ("lift", "lift_cube", 1): "x"})
    more = _results_file(tmp_path / "a2", {("lift", "lift_cube", 2): "x"})
    cand = _results_file(
        tmp_path / "b", {("lift", "lift_cube", s): None for s in range(3)} | {("lift", "lift_cube", 9): None}
    )
    files, pooled = load_pooled([first, more / "results.json"])
    assert [f.parent.name for f in files] == ["a1", "a2"] and len(pooled) == 3
    out = tmp_path / "diff.json"
    assert main([f"--baseline=[{first},{more}]", "--candidate", str(cand), "--output_json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert (result["all"]["episodes"], result["all"]["won"], result["only_candidate"]) == (3, 2, 1)
    assert result["candidate"] == [str(cand / "results.json")]
    capsys.readouterr()
    with pytest.raises(ValueError, match="is in both"):
        load_pooled([first, first])
    assert main(["--baseline", f"[{first},{first}]", "--candidate", str(cand)]) == 1
    assert "pool disjoint seeds only" in capsys.readouterr().err


def test_bad_input_is_one_clear_error(tmp_path, capsys):
    assert main(["--baseline", str(tmp_path / "nowhere")]) == 1
    assert "--candidate are both required" in capsys.readouterr().err
    assert main(["--baseline", str(tmp_path / "nowhere"), "--candidate", str(tmp_path)]) == 1
    assert f"{tmp_path / 'nowhere'}: no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match=r"bad\.json: not JSON"):
        load_outcomes(bad)
    bad.write_text(json.dumps({"episodes": [{"task": "lift", "variation": "lift_cube", "success": True}]}))
    with pytest.raises(ValueError, match=r"bad\.json: episode 0 lacks task, variation, seed or success"):
        load_outcomes(bad)
    bad.write_text(json.dumps({"mean_success": 1.0}))
    with pytest.raises(ValueError, match="no 'episodes' list"):
        load_outcomes(bad)
    a = _results_file(tmp_path / "a", {("lift", "lift_cube", 1): None})
    b = _results_file(tmp_path / "b", {("lift", "lift_cube", 2): None})
    assert main(["--baseline", str(a), "--candidate", str(b)]) == 1
    assert "share no episode" in capsys.readouterr().err
