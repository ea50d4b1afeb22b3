"""How far apart the text encoder puts the suite's instructions, and what a fixed rescaling of its features changes.

The policy reads an instruction through the frozen encoder's token states (sigma_policy/text_encoder.py), all of
them flattened in order by ``lang_film`` (sigma_policy/conditioning.py). For the network to follow an instruction, what
tells two variations of a task apart (Stack's order, PickPlace's object) must stand out against what tells a
variation's paraphrases apart, which the network has to ignore. This benchmark measures that on the flattened token
states of every instruction of the registered tasks (sigma_data/suite.py): the mean Euclidean distance between
paraphrases of one variation (``within``), between instructions of two variations of one task (``between``) and
of two tasks (``tasks``), and per multi-variation task the ratio ``between / within`` and the distance of its two
canonical instructions (``canonical``), under three fixed rescalings of the features:

- ``raw``: the encoder's output;
- ``standardised``: each feature dimension centred and divided by its standard deviation over every token row of
  every instruction (constant dimensions left as they are);
- ``whitened``: the instructions' principal directions each scaled to the same variance (ZCA within their span).

``readout`` says whether a network could tell the variations apart from these features at all, paraphrases it was
not trained on included: each instruction in turn is left out, a linear ridge readout of the variation is fitted on
the others (closed form, with an intercept, on features scaled to unit mean norm about their mean) and asked the left-out one's variation.

Centring and rescaling a dimension cannot change a ratio of distances that every dimension contributes to alike;
whitening puts N instructions at the corners of a regular simplex, where every pair is as far apart as every other
(all ratios 1): it removes what tells paraphrases apart only by removing what makes them alike.

    python -m benchmarks.bench_instructions          # MiniLM, offline; --output JSON
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import draccus
import torch
from torch import Tensor


@dataclass
class InstructionsConfig:
    """Options of the instruction-geometry benchmark."""

    text_encoder: str = "minilm"  # minilm (offline) | clip (needs --text_encoder_path)
    text_encoder_path: str | None = None
    output: Path | None = None  # JSON with every number; default: none (stdout only)


def standardised(x: Tensor) -> Tensor:
    """``x (N, L, D)`` with each dimension centred and scaled to unit deviation over all N·L token rows."""
    rows = x.reshape(-1, x.shape[-1])
    std = rows.std(0)
    return (x - rows.mean(0)) / torch.where(std > 1e-6, std, torch.ones_like(std))


def whitened(x: Tensor) -> Tensor:
    """``x (N, ...)`` flattened, centred and rescaled along its principal directions to equal variance."""
    flat = x.reshape(len(x), -1).double()
    centred = flat - flat.mean(0)
    u, s, _ = torch.linalg.svd(centred, full_matrices=False)
    keep = s > 1e-8 * s.max()
    return (u[:, keep] * s[keep].pow(2).mean().sqrt()).float()


def geometry(features: Tensor, labels: list[tuple[str, str]], canonical: dict[str, tuple[int, int]]) -> dict:
    """Mean pairwise distances of ``features (N, ...)`` by the ``(task, variation)`` of each row, and per task of
    ``canonical`` (task -> the rows of its two canonical instructions) ``between / within`` and their distance."""
    flat = features.reshape(len(features), -1).double()
    dist = torch.cdist(flat, flat)
    groups: dict[str, list[float]] = {"within": [], "between": [], "tasks": []}
    per_task: dict[str, dict[str, list[float]]] = {}
    for i in range(len(labels)):
        for j in range(i + 1, len(labels)):
            (ti, vi), (tj, vj) = labels[i], labels[j]
            kind = "tasks" if ti != tj else "within" if vi == vj else "between"
            groups[kind].append(float(dist[i, j]))
            if kind != "tasks":
                per_task.setdefault(ti, {"within": [], "between": []})[kind].append(float(dist[i, j]))
    out = {k: sum(v) / len(v) for k, v in groups.items() if v}
    for task, (a, b) in canonical.items():
        d = per_task[task]
        within = sum(d["within"]) / len(d["within"])
        out[task] = {
            "between_over_within": sum(d["between"]) / len(d["between"]) / within,
            "canonical_over_within": float(dist[a, b]) / within,
        }
    return out


def readout_misses(features: Tensor, labels: list[tuple[str, str]], ridge: float = 1e-3) -> list[int]:
    """Rows of ``features (N, ...)`` whose ``(task, variation)`` a linear ridge readout fitted on the other rows
    gets wrong (leave one out; the readout regresses the one-hot variation and takes its largest output)."""
    x = features.reshape(len(features), -1).double()
    x = x / (x - x.mean(0)).norm(dim=1).mean()
    names = sorted(set(labels))
    y = torch.nn.functional.one_hot(torch.tensor([names.index(v) for v in labels]), len(names)).double()
    misses = []
    for i in range(len(x)):
        rest = [j for j in range(len(x)) if j != i]
        # Centred on the fitted rows alone, with the intercept (their mean one-hot) added back to the prediction.
        x_mean, y_mean = x[rest].mean(0), y[rest].mean(0)
        xr = x[rest] - x_mean
        alpha = torch.linalg.solve(xr @ xr.T + ridge * torch.eye(len(rest), dtype=x.dtype), y[rest] - y_mean)
        if int(((x[i] - x_mean) @ xr.T @ alpha + y_mean).argmax()) != names.index(labels[i]):
            misses.append(i)
    return misses


def main(cfg: InstructionsConfig) -> dict:
    from sigma_data.suite import TASKS
    from sigma_policy.text_encoder import make_text_encoder

    labels, texts, canonical = [], [], {}
    for task in TASKS.values():
        for variation in task.variations:
            for text in variation.instructions:
                labels.append((task.name, variation.name))
                texts.append(text)
        if len(task.variations) > 1:
            first = [texts.index(v.instruction) for v in task.variations[:2]]
            canonical[task.name] = (first[0], first[1])
    feats = make_text_encoder(cfg.text_encoder, cfg.text_encoder_path, allow_table=False).encode(texts)
    tokens = feats.tokens.float()
    report = {
        "encoder": cfg.text_encoder,
        "instructions": len(texts),
        "sentence_cosine_canonical": {
            task: float(torch.cosine_similarity(feats.sentence[a], feats.sentence[b], dim=0))
            for task, (a, b) in canonical.items()
        },
        "geometry": {},
    }
    for name, f in (("raw", tokens), ("standardised", standardised(tokens)), ("whitened", whitened(tokens))):
        misses = readout_misses(f, labels)
        report["geometry"][name] = geometry(f, labels, canonical) | {
            "readout": len(texts) - len(misses),
            "readout_misses": [texts[i] for i in misses],
        }
    if cfg.output is not None:
        cfg.output.write_text(json.dumps(report, indent=2))
    print(table(report))
    return report


def table(report: dict) -> str:
    """The report as a markdown table: one row per rescaling."""
    tasks = list(report["sentence_cosine_canonical"])
    head = [
        "features",
        "readout",
        "within",
        "between",
        "tasks",
        *(f"{t} between/within, canonical/within" for t in tasks),
    ]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, g in report["geometry"].items():
        cells = [name, f"{g['readout']}/{report['instructions']}"]
        cells += [f"{g[k]:.1f}" for k in ("within", "between", "tasks")]
        cells += [f"{g[t]['between_over_within']:.2f}, {g[t]['canonical_over_within']:.2f}" for t in tasks]
        rows.append("| " + " | ".join(cells) + " |")
    cosines = ", ".join(f"{t} {c:.3f}" for t, c in report["sentence_cosine_canonical"].items())
    rows.append(f"\nsentence features of the canonical pair, cosine: {cosines}")
    rows.append(f"bench_instructions: {report['instructions']} instructions of {report['encoder']}")
    return "\n".join(rows)


if __name__ == "__main__":
    main(draccus.parse(InstructionsConfig))
