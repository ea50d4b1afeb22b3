"""``sigma-diff``: two closed-loop evaluations compared episode by episode, on the seeds they share.

Two ``sigma-eval`` runs on the same seeds see the same scenes (a variation's scene is a function of its seed), so
their episodes pair up: a recipe change, a test-time option or a second training seed is then judged by the
episodes it won and lost, not by two independent rates whose intervals overlap. For the episodes both results hold
(matched on task, variation and seed) this prints, per variation and over all of them:

* each run's successes, and the episodes the candidate won (it succeeded, the baseline did not) and lost;
* the exact McNemar test of the discordant pairs (two-sided binomial test of won against lost at 1/2; McNemar,
  Psychometrika 1947, https://doi.org/10.1007/BF02295996);
* the difference of the success rates with its 95% interval for paired proportions, Newcombe's method 10
  (Wilson intervals of each rate combined with the pairs' correlation; Newcombe, Statistics in Medicine 1998,
  https://doi.org/10.1002/(SICI)1097-0258(19981130)17:22%3C2635::AID-SIM954%3E3.0.CO;2-C);
* each run's failures by kind (``sigma-eval``'s reasons, :data:`pipelines.failures.FAILURE_KINDS`).

Each side may be several evaluations of one policy on disjoint seeds (``--baseline '[A,B]'``): their episodes are
pooled, so 20 episodes per variation and 20 more scored later compare as 40.

An episode that ended in an error counts as a failure, as in ``sigma-eval``'s own table; a failure that a results.json
written before ``sigma-eval`` recorded reasons holds without one is counted as "no reason recorded".

Example::

    sigma-diff --baseline outputs/bench_suite/runs/seed0/eval --candidate outputs/bench_suite/runs/seed0/eval_tta15
    sigma-diff --baseline '[runs/a/eval,runs/a/eval_seeds100020]' --candidate '[runs/b/eval,runs/b/eval_seeds100020]'
"""

from __future__ import annotations

import json
import math
import sys
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import draccus

from pipelines.evaluate import wilson_interval
from pipelines.failures import FAILURE_KINDS, failure_kind

EpisodeKey = tuple[str, str, int]  # task, variation, seed


@dataclass
class DiffConfig:
    """Options of ``sigma-diff``."""

    # The reference evaluation: a sigma-eval results.json, or the directory that holds it; or a list '[A,B]' of
    # evaluations of one policy on disjoint seeds, pooled.
    baseline: list[Path] = field(default_factory=list)
    # The evaluation compared with it, on the same seeds (one, or a list as for the baseline).
    candidate: list[Path] = field(default_factory=list)
    # Also write the comparison as JSON here (optional).
    output_json: Path | None = None


@dataclass(frozen=True)
class Pairs:
    """Paired outcomes: ``both`` succeeded in both runs, ``won`` only the candidate, ``lost`` only the baseline."""

    both: int
    won: int
    lost: int
    neither: int

    @property
    def n(self) -> int:
        return self.both + self.won + self.lost + self.neither

    @property
    def baseline_successes(self) -> int:
        return self.both + self.lost

    @property
    def candidate_successes(self) -> int:
        return self.both + self.won


def pair_counts(baseline: list[bool], candidate: list[bool]) -> Pairs:
    """Count the four kinds of pair; the two lists are outcomes of the same episodes, in the same order."""
    if len(baseline) != len(candidate):
        raise ValueError(f"paired outcomes must have equal length, got {len(baseline)} and {len(candidate)}")
    counts = Counter(zip(baseline, candidate, strict=True))
    return Pairs(counts[(True, True)], counts[(False, True)], counts[(True, False)], counts[(False, False)])


def mcnemar_exact_p(won: int, lost: int) -> float:
    """Two-sided exact McNemar p: the binomial probability, at 1/2, of a split of the discordant pairs at least as
    uneven as ``won`` : ``lost``. 1.0 when no pair is discordant."""
    n = won + lost
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, k) for k in range(min(won, lost) + 1)) / 2**n
    return min(1.0, 2.0 * tail)


def paired_difference_interval(pairs: Pairs, z: float = 1.96) -> tuple[float, float, float]:
    """The candidate's success rate minus the baseline's, with its 95% interval (Newcombe's method 10 for paired
    proportions): (difference, low, high). The pairs' correlation is taken as 0 when a margin is empty."""
    n = pairs.n
    if n == 0:
        raise ValueError("no paired episodes")
    p_c, p_b = pairs.candidate_successes / n, pairs.baseline_successes / n
    l_c, u_c = wilson_interval(pairs.candidate_successes, n, z)
    l_b, u_b = wilson_interval(pairs.baseline_successes, n, z)
    a, b, c, d = pairs.both, pairs.lost, pairs.won, pairs.neither  # baseline rows, candidate columns
    margins = (a + b) * (c + d) * (a + c) * (b + d)
    phi = (a * d - b * c) / math.sqrt(margins) if margins else 0.0
    diff = p_c - p_b
    below = math.sqrt(max(0.0, (p_c - l_c) ** 2 - 2 * phi * (p_c - l_c) * (u_b - p_b) + (u_b - p_b) ** 2))
    above = math.sqrt(max(0.0, (u_c - p_c) ** 2 - 2 * phi * (u_c - p_c) * (p_b - l_b) + (p_b - l_b) ** 2))
    return diff, max(-1.0, diff - below), min(1.0, diff + above)


def load_outcomes(path: Path) -> tuple[Path, dict[EpisodeKey, dict]]:
    """``sigma-eval``'s episodes by (task, variation, seed), read from a results.json or the directory holding one.
    Raises ValueError naming the file when it is missing, not JSON, or not a sigma-eval result."""
    path = Path(path)
    file = path / "results.json" if path.is_dir() else path
    try:
        data = json.loads(file.read_text())
    except FileNotFoundError:
        raise ValueError(f"{file}: no such file (sigma-eval's results.json or its directory)") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{file}: not JSON ({e})") from None
    episodes = data.get("episodes") if isinstance(data, dict) else None
    if not isinstance(episodes, list):
        raise ValueError(f"{file}: no 'episodes' list; is it a sigma-eval results.json?")
    out: dict[EpisodeKey, dict] = {}
    for i, ep in enumerate(episodes):
        try:
            key = (str(ep["task"]), str(ep["variation"]), int(ep["seed"]))
            ep["success"] = bool(ep["success"])
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{file}: episode {i} lacks task, variation, seed or success ({e!r})") from None
        if key in out:
            raise ValueError(f"{file}: episode {key} appears twice")
        out[key] = ep
    return file, out


# The kind of a failed episode whose results.json holds no reason (written before sigma-eval recorded one).
UNRECORDED = "no reason recorded"


def load_pooled(paths: list[Path]) -> tuple[list[Path], dict[EpisodeKey, dict]]:
    """:func:`load_outcomes` of each evaluation, pooled; ValueError naming both files when an episode (task,
    variation, seed) is in two of them."""
    files: list[Path] = []
    pooled: dict[EpisodeKey, dict] = {}
    origin: dict[EpisodeKey, Path] = {}
    for path in paths:
        file, outcomes = load_outcomes(path)
        for key, episode in outcomes.items():
            if key in pooled:
                raise ValueError(
                    f"episode {key} is in both {origin[key]} and {file}; pool disjoint seeds only"
                )
            pooled[key], origin[key] = episode, file
        files.append(file)
    return files, pooled


def parse_args(argv: list[str]) -> DiffConfig:
    """``sigma-diff``'s arguments; ``--baseline A`` is read as ``--baseline [A]``, so one evaluation needs no
    brackets (draccus reads a list only in brackets)."""
    return draccus.parse(DiffConfig, args=_single_runs_as_lists(argv))


def _single_runs_as_lists(argv: list[str]) -> list[str]:
    out, wrap = [], False
    for arg in argv:
        name, eq, value = arg.partition("=")
        if wrap and not arg.startswith(("[", "--")):
            arg = f"[{arg}]"
        elif name in ("--baseline", "--candidate") and eq and not value.startswith("["):
            arg = f"{name}=[{value}]"
        wrap = arg in ("--baseline", "--candidate")
        out.append(arg)
    return out


def _failure_kind(episode: dict) -> str:
    if episode.get("failure"):
        return failure_kind(episode["failure"])
    return "error" if episode.get("error") else UNRECORDED


def _failures(episodes: list[dict]) -> dict[str, int]:
    kinds = Counter(_failure_kind(e) for e in episodes if not e["success"])
    order = [*FAILURE_KINDS, *sorted(set(kinds) - set(FAILURE_KINDS))]
    return {kind: kinds[kind] for kind in order if kinds[kind]}


def _row(pairs: Pairs) -> dict:
    diff, lo, hi = paired_difference_interval(pairs)
    return {
        "episodes": pairs.n,
        "baseline_successes": pairs.baseline_successes,
        "candidate_successes": pairs.candidate_successes,
        "won": pairs.won,
        "lost": pairs.lost,
        "difference": diff,
        "difference_ci95": [lo, hi],
        "mcnemar_p": mcnemar_exact_p(pairs.won, pairs.lost),
    }


def compare(baseline: dict[EpisodeKey, dict], candidate: dict[EpisodeKey, dict]) -> dict:
    """The paired comparison over the episodes both runs hold: per variation, over all, and the failures by kind.
    Raises ValueError when they share no episode."""
    shared = sorted(set(baseline) & set(candidate))
    if not shared:
        raise ValueError(
            "the two evaluations share no episode (task, variation and seed); evaluate both on the same seeds"
        )

    def pairs_of(keys: list[EpisodeKey]) -> Pairs:
        return pair_counts([baseline[k]["success"] for k in keys], [candidate[k]["success"] for k in keys])

    groups: dict[tuple[str, str], list[EpisodeKey]] = defaultdict(list)
    for key in shared:
        groups[key[:2]].append(key)
    rows = [
        {"task": task, "variation": variation, **_row(pairs_of(keys))}
        for (task, variation), keys in sorted(groups.items())
    ]
    return {
        "variations": rows,
        "all": _row(pairs_of(shared)),
        "failures": {
            "baseline": _failures([baseline[k] for k in shared]),
            "candidate": _failures([candidate[k] for k in shared]),
        },
        "only_baseline": len(set(baseline) - set(candidate)),
        "only_candidate": len(set(candidate) - set(baseline)),
    }


def _points(x: float) -> str:
    return f"{100 * x:+.0f}"


def markdown(result: dict) -> str:
    """The comparison as a Markdown table (one row per variation, then all) and the failures by kind."""
    lines = [
        "| task | variation | episodes | baseline | candidate | won / lost | difference, points (95% CI) | McNemar p |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in [*result["variations"], {"task": "**all**", "variation": "", **result["all"]}]:
        lo, hi = r["difference_ci95"]
        lines.append(
            f"| {r['task']} | {r['variation']} | {r['episodes']} | {r['baseline_successes']} "
            f"| {r['candidate_successes']} | {r['won']} / {r['lost']} | {_points(r['difference'])} "
            f"({_points(lo)} to {_points(hi)}) | {r['mcnemar_p']:.3g} |"
        )
    lines.append("")
    for arm in ("baseline", "candidate"):
        kinds = result["failures"][arm]
        lines.append(f"{arm} failures: " + (", ".join(f"{k} {n}" for k, n in kinds.items()) or "none"))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    cfg = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        if not cfg.baseline or not cfg.candidate:
            raise ValueError(
                "--baseline and --candidate are both required (sigma-eval outputs or results.json)"
            )
        base_files, base = load_pooled(cfg.baseline)
        cand_files, cand = load_pooled(cfg.candidate)
        result = compare(base, cand)
    except ValueError as e:
        print(f"sigma-diff: {e}", file=sys.stderr)
        return 1
    result["baseline"], result["candidate"] = [str(f) for f in base_files], [str(f) for f in cand_files]
    print(markdown(result))
    if cfg.output_json is not None:
        cfg.output_json.parent.mkdir(parents=True, exist_ok=True)
        cfg.output_json.write_text(json.dumps(result, indent=2))
    a = result["all"]
    lo, hi = a["difference_ci95"]
    unmatched = result["only_baseline"] + result["only_candidate"]
    print(
        f"sigma-diff: {a['candidate_successes']}/{a['episodes']} against {a['baseline_successes']}/{a['episodes']} "
        f"on shared episodes, {a['won']} won / {a['lost']} lost (exact McNemar p = {a['mcnemar_p']:.3g}), "
        f"difference {_points(a['difference'])} points ({_points(lo)} to {_points(hi)})"
        + (f"; {unmatched} episodes in only one run were left out" if unmatched else "")
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
