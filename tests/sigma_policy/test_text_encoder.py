"""Text encoders: a tiny CLIP built and saved by the test, the packaged MiniLM, per-instruction caching, and feature
tables (the encoder's exact outputs read back; every way a table can be wrong refused by name)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file
from transformers import CLIPTextConfig, CLIPTextModel

from sigma_policy.text_encoder import (
    TEXT_FEATURES_ENV,
    CLIPTextEncoder,
    MiniLMTextEncoder,
    TextFeatureTable,
    make_text_encoder,
    minilm_model_dir,
    save_text_features,
    task_contrast,
)


def bytes_to_unicode() -> dict[int, str]:
    """GPT-2 / CLIP byte-level alphabet: printable bytes map to themselves, the rest to code points >= 256."""
    keep = [*range(ord("!"), ord("~") + 1), *range(ord("¡"), ord("¬") + 1), *range(ord("®"), ord("ÿ") + 1)]
    extra = [b for b in range(256) if b not in keep]
    return dict(
        zip(keep + extra, [chr(b) for b in keep] + [chr(256 + i) for i in range(len(extra))], strict=True)
    )


WORDS = ["pick", "up", "the", "red", "cube", "stack", "on", "green", "open", "door"]


def _tiny_clip(tmp: Path) -> Path:
    """A random 2-layer CLIP text tower with a small byte-level BPE vocabulary, saved like a hub checkout."""
    chars = list(bytes_to_unicode().values())
    vocab_list = chars + [c + "</w>" for c in chars]
    merges = []
    for w in WORDS:  # merge each word left to right so it becomes one token "word</w>"
        cur = w[0]
        for i, c in enumerate(w[1:], 1):
            nxt = c + ("</w>" if i == len(w) - 1 else "")
            merges.append((cur, nxt))
            cur = cur + nxt
            vocab_list.append(cur)
    vocab_list += ["<|startoftext|>", "<|endoftext|>"]
    vocab = {t: i for i, t in enumerate(dict.fromkeys(vocab_list))}
    merges = list(dict.fromkeys(merges))
    from transformers import CLIPTokenizer

    CLIPTokenizer(vocab=vocab, merges=merges).save_pretrained(tmp)
    eos = vocab["<|endoftext|>"]
    cfg = CLIPTextConfig(
        vocab_size=len(vocab), hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=4,
        max_position_embeddings=77, bos_token_id=vocab["<|startoftext|>"], eos_token_id=eos, pad_token_id=eos,
    )  # fmt: skip
    torch.manual_seed(0)
    CLIPTextModel(cfg).save_pretrained(tmp)
    return tmp


def test_clip_encoder_features_and_cache(tmp_path: Path) -> None:
    enc = CLIPTextEncoder(str(_tiny_clip(tmp_path)), max_length=77)
    assert (enc.token_dim, enc.sentence_dim, enc.max_length) == (32, 32, 77)
    assert not any(p.requires_grad for p in enc.parameters())
    texts = ["pick up the red cube", "stack red on green", "pick up the red cube"]
    feats = enc.encode(texts)
    assert feats.tokens.shape == (3, 77, 32) and feats.sentence.shape == (3, 32)
    assert enc.calls == 1
    torch.testing.assert_close(feats.tokens[0], feats.tokens[2])
    # sentence = the final-LN state at the end-of-text token (no projection).
    ids = enc.tokenizer(texts[0])["input_ids"]
    assert len(ids) == 7  # <sot> pick up the red cube <eot>: the tiny BPE merges whole words
    torch.testing.assert_close(feats.sentence[0], feats.tokens[0, len(ids) - 1])
    # The 70 padding states behind the instruction's 7 tokens are not zeros (the network reads all 77).
    assert feats.tokens[0, 7:].abs().amax() > 0
    # Cached instructions never re-run the model; a new one runs it once more.
    enc.encode(["stack red on green"])
    assert enc.calls == 1
    enc.encode(["open door", "pick up the red cube", "open door"])
    assert enc.calls == 2
    # Batching does not change the features.
    fresh = CLIPTextEncoder(str(tmp_path))
    torch.testing.assert_close(fresh.encode(["open door"]).tokens, enc.encode(["open door"]).tokens)


def test_make_text_encoder_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="name_or_path"):
        make_text_encoder("clip")
    with pytest.raises(ValueError, match="unknown"):
        make_text_encoder("t5")
    with pytest.raises(OSError, match=str(tmp_path)):
        CLIPTextEncoder(str(tmp_path))


def test_minilm_matches_sentence_transformers_and_caches() -> None:
    from sentence_transformers import SentenceTransformer

    enc = make_text_encoder("minilm")
    assert isinstance(enc, MiniLMTextEncoder) and enc.token_dim == 384
    texts = ["pick up the red cube", "open the door", "pick up the red cube"]
    feats = enc.encode(texts)
    assert feats.tokens.shape == (3, 77, 384) and enc.calls == 1
    ref = SentenceTransformer(str(minilm_model_dir()), device="cpu").encode(texts, convert_to_tensor=True)
    torch.testing.assert_close(feats.sentence, ref, atol=1e-5, rtol=0)
    # Real pretrained weights: paraphrases are closer than unrelated instructions.
    s = enc.encode(["lift the red block", "open the door"]).sentence
    assert float(s[0] @ feats.sentence[0]) > float(s[1] @ feats.sentence[0]) + 0.2


def test_minilm_refuses_wrong_checksum() -> None:
    with pytest.raises(ValueError, match="SHA-256"):
        MiniLMTextEncoder(expected_sha256="0" * 64)


def test_minilm_loads_without_transformers_report_and_restores_its_settings():
    """The verified MiniLM checkpoint loads without transformers' key table and progress bar (printed on every
    lerobot-train start before), and transformers' own logging settings are left as they were."""
    import subprocess
    import sys

    code = (
        "from transformers.utils import logging as L\n"
        "from sigma_policy.text_encoder import MiniLMTextEncoder\n"
        "MiniLMTextEncoder()\n"
        "print(L.get_verbosity(), L.is_progress_bar_enabled())\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split() == ["30", "True"]  # WARNING and bars on: the defaults, restored
    assert "LOAD REPORT" not in proc.stderr and "Loading weights" not in proc.stderr, proc.stderr[-3000:]


TABLE_INSTRUCTIONS = ["pick up the red cube", "stack red on green", "open the door"]


@pytest.fixture()
def clip(tmp_path: Path) -> tuple[str, CLIPTextEncoder]:
    path = str(_tiny_clip(tmp_path / "clip"))
    return path, CLIPTextEncoder(path)


def test_table_returns_the_encoders_features(clip, tmp_path: Path, monkeypatch) -> None:
    path, enc = clip
    table_file = save_text_features(
        enc, [*TABLE_INSTRUCTIONS, TABLE_INSTRUCTIONS[0]], tmp_path / "f.safetensors"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip", "f.safetensors"]  # no temporary left
    monkeypatch.setenv(TEXT_FEATURES_ENV, str(table_file))
    table = make_text_encoder("clip", path)
    assert isinstance(table, TextFeatureTable)
    assert (table.token_dim, table.sentence_dim, table.max_length) == (32, 32, 77)
    assert table.identity == enc.identity == f"clip:{path}"
    want, got = enc.encode(TABLE_INSTRUCTIONS[::-1]), table.encode(TABLE_INSTRUCTIONS[::-1])
    assert torch.equal(want.tokens, got.tokens) and torch.equal(want.sentence, got.sentence)
    with pytest.raises(KeyError, match=r"f\.safetensors: no features for the instruction\(s\) \['lift it'\]"):
        table.encode(["lift it"])
    # the encoder itself when asked for (sigma-encode), or with the variable unset
    assert isinstance(make_text_encoder("clip", path, allow_table=False), CLIPTextEncoder)
    monkeypatch.delenv(TEXT_FEATURES_ENV)
    assert isinstance(make_text_encoder("clip", path), CLIPTextEncoder)


def test_table_of_another_encoder_is_refused(clip, tmp_path: Path, monkeypatch) -> None:
    _, enc = clip
    table_file = save_text_features(enc, TABLE_INSTRUCTIONS, tmp_path / "f.safetensors")
    monkeypatch.setenv(TEXT_FEATURES_ENV, str(table_file))
    with pytest.raises(
        ValueError, match=r"f\.safetensors: features of the encoder 'clip:.*', but the policy reads"
    ):
        make_text_encoder("minilm")
    with pytest.raises(ValueError, match=r"features of the encoder"):
        make_text_encoder("clip", "openai/clip-vit-base-patch32")


def test_bad_tables_are_named(clip, tmp_path: Path) -> None:
    _, enc = clip
    with pytest.raises(FileNotFoundError, match=rf"{TEXT_FEATURES_ENV}=.*missing\.safetensors: no such file"):
        TextFeatureTable(tmp_path / "missing.safetensors")
    good = save_text_features(enc, TABLE_INSTRUCTIONS, tmp_path / "good.safetensors")
    cut = tmp_path / "cut.safetensors"
    cut.write_bytes(good.read_bytes()[:200])
    with pytest.raises(ValueError, match=r"cut\.safetensors: not a readable text-feature table"):
        TextFeatureTable(cut)
    foreign = tmp_path / "foreign.safetensors"
    save_file({"weight": torch.zeros(2)}, foreign)
    with pytest.raises(ValueError, match=r"foreign\.safetensors: not a sigma text-feature table"):
        TextFeatureTable(foreign)
    table = TextFeatureTable(good)
    meta = {"format": "sigma-text-features/1", "encoder": table.identity, "max_length": "77"}
    nan = tmp_path / "nan.safetensors"
    tokens = torch.full((1, 77, 32), float("nan"))
    save_file(
        {"tokens": tokens, "sentence": torch.zeros(1, 32)}, nan, metadata=meta | {"instructions": '["a"]'}
    )
    with pytest.raises(ValueError, match=r"nan\.safetensors: the features hold NaN"):
        TextFeatureTable(nan)
    short = tmp_path / "short.safetensors"
    save_file(
        {"tokens": torch.zeros(2, 77, 32), "sentence": torch.zeros(2, 32)}, short,
        metadata=meta | {"instructions": '["a"]'},
    )  # fmt: skip
    with pytest.raises(ValueError, match=r"short\.safetensors: 1 instructions but tokens \(2, 77, 32\)"):
        TextFeatureTable(short)
    with pytest.raises(ValueError, match="at least one instruction"):
        save_text_features(enc, [], tmp_path / "empty.safetensors")


def test_a_table_that_holds_the_tokenizers_mask_still_reads(clip, tmp_path: Path) -> None:
    """Tables written in sessions 83-85 also hold a ``mask`` tensor (the tokenizer's attention mask); it is ignored
    and the features are the encoder's; new tables hold the features only."""
    _, enc = clip
    feats = enc.encode(TABLE_INSTRUCTIONS)
    meta = {
        "format": "sigma-text-features/1",
        "encoder": enc.identity,
        "max_length": "77",
        "instructions": json.dumps(TABLE_INSTRUCTIONS),
    }
    old = tmp_path / "old.safetensors"
    tensors = {"tokens": feats.tokens.contiguous(), "sentence": feats.sentence.contiguous()}
    save_file({**tensors, "mask": torch.ones(len(TABLE_INSTRUCTIONS), 77)}, old, metadata=meta)
    got = TextFeatureTable(old).encode(TABLE_INSTRUCTIONS)
    assert torch.equal(got.tokens, feats.tokens) and torch.equal(got.sentence, feats.sentence)
    written = save_text_features(enc, TABLE_INSTRUCTIONS, tmp_path / "new.safetensors")
    with safe_open(written, "pt") as f:
        assert sorted(f.keys()) == ["sentence", "tokens"]


def test_task_contrast_amplifies_what_tells_a_tasks_instructions_apart() -> None:
    """Each instruction's deviation from its task's mean is scaled by the gain; one alone in its task is its own
    mean (unchanged), and the gain gives the deviations the states' root-mean-square norm."""
    g = torch.Generator().manual_seed(0)
    shared = torch.randn(1, 6, 4, generator=g)
    stack = shared + 0.1 * torch.randn(2, 6, 4, generator=g)  # two orders: nearly the same states
    lift = torch.randn(1, 6, 4, generator=g)
    tokens = torch.cat([stack, lift])
    means, gain = task_contrast(tokens, ["stack", "stack", "lift"])
    torch.testing.assert_close(means[0], stack.mean(0))
    torch.testing.assert_close(means[1], stack.mean(0))
    torch.testing.assert_close(means[2], lift[0])
    deviation = (stack - stack.mean(0)).flatten(1).pow(2).sum(1).mean()
    assert gain.item() == pytest.approx((tokens.flatten(1).pow(2).sum(1).mean() / deviation).sqrt().item())
    assert gain > 5
    read = means + gain * (tokens - means)
    before = torch.nn.functional.cosine_similarity(stack[0].flatten(), stack[1].flatten(), dim=0)
    after = torch.nn.functional.cosine_similarity(read[0].flatten(), read[1].flatten(), dim=0)
    assert before > 0.95 and after < before - 0.5
    torch.testing.assert_close(read[2], lift[0])


def test_task_contrast_without_two_instructions_of_a_task_changes_nothing() -> None:
    tokens = torch.randn(2, 3, 4)
    for same_task in (tokens, tokens[:1].expand(2, 3, 4)):
        tasks = ["lift", "stack"] if same_task is tokens else ["stack", "stack"]
        means, gain = task_contrast(same_task, tasks)
        assert gain.item() == 1.0
        torch.testing.assert_close(means + gain * (same_task - means), same_task)
    with pytest.raises(ValueError, match="3 instructions"):
        task_contrast(tokens, ["a", "b", "c"])
