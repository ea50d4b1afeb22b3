"""The grouped multi-frame query returns exactly what LeRobot's own returns, with far fewer decodes."""

from __future__ import annotations

import torch
from lerobot.datasets.dataset_reader import DatasetReader
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from sigma_policy import lerobot_patches
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


def test_patched_query_matches_lerobot_original(tmp_path):
    assert lerobot_patches.install()  # idempotent
    assert DatasetReader._query_hf_dataset is lerobot_patches._grouped_query_hf_dataset
    original = lerobot_patches._grouped_query_hf_dataset.original

    ds = _tiny_goal_dataset(tmp_path)
    keys = [k for k in ds.features if k.startswith("observation.")]
    reader = ds._ensure_reader()
    for idx in (0, 3, len(ds) - 1):  # the last frame's goal index is clamped to itself
        ep = int(ds.hf_dataset[idx]["episode_index"])
        query, _ = reader._get_query_indices(idx, ep)
        fast = lerobot_patches._grouped_query_hf_dataset(reader, query)
        slow = original(reader, query)
        assert fast.keys() == slow.keys() and len(fast) == len(keys)
        for key in fast:
            assert torch.equal(fast[key], slow[key]), key
    item = ds[1]
    assert item["observation.state"].shape[0] == 2

    # The whole item: the patched get_item (current row read without the queried columns) equals LeRobot's.
    assert DatasetReader.get_item is lerobot_patches._get_item_without_double_decode
    # A second pass reads every sample from the decoded-row cache: still the same items.
    original_get_item = lerobot_patches._get_item_without_double_decode.original
    for _ in range(2):
        for idx in range(len(ds)):
            _assert_same_item(reader.get_item(idx), original_get_item(reader, idx), idx)
    assert lerobot_patches._CACHES[reader].used > 0


def _assert_same_item(fast: dict, slow: dict, idx: int) -> None:
    assert fast.keys() == slow.keys(), idx
    for key, value in slow.items():
        if torch.is_tensor(value):
            assert fast[key].dtype == value.dtype and torch.equal(fast[key], value), (idx, key)
        else:
            assert fast[key] == value, (idx, key)


def _tiny_goal_dataset(tmp_path) -> LeRobotDataset:
    """A tiny keyframe dataset read as sigma reads it: every observation key at the current and the next frame."""
    root = write_tiny_keyframe_dataset(tmp_path / "ds")
    plain = LeRobotDataset("local/tiny", root=root, video_backend="pyav")
    keys = [k for k in plain.features if k.startswith("observation.")]
    return LeRobotDataset(
        "local/tiny",
        root=root,
        delta_timestamps={k: [0.0, 1 / plain.fps] for k in keys},
        video_backend="pyav",
    )


def test_read_cache_keeps_decoded_rows_within_its_budget(tmp_path, monkeypatch):
    """Cached reads are the first reads' tensors, never more than SIGMA_READ_CACHE_MB is kept, 0 turns it off,
    and what a caller adds to a returned item does not leak into the next read."""
    assert lerobot_patches.install()
    ds = _tiny_goal_dataset(tmp_path)
    first = [ds[i] for i in range(len(ds))]
    reader = ds._ensure_reader()
    full = lerobot_patches._CACHES[reader]
    assert full.used > 0 and len(full.items) > 0
    first[0]["added_by_caller"] = 1
    for idx in range(len(ds)):
        _assert_same_item(
            ds[idx], first[idx] if idx else {k: v for k, v in first[0].items() if k != "added_by_caller"}, idx
        )

    monkeypatch.setenv("SIGMA_READ_CACHE_MB", str(full.used / 2 / 2**20))
    small = _tiny_goal_dataset(tmp_path / "small")
    items = [small[i] for i in range(len(small))]
    cache = lerobot_patches._CACHES[small._ensure_reader()]
    assert 0 < cache.used <= full.used / 2
    for idx in range(len(small)):
        _assert_same_item(small[idx], items[idx], idx)

    monkeypatch.setenv("SIGMA_READ_CACHE_MB", "0")
    off = _tiny_goal_dataset(tmp_path / "off")
    _assert_same_item(off[1], items[1], 1)
    assert off._ensure_reader() not in lerobot_patches._CACHES


def test_a_spawned_worker_gets_the_patch_with_the_dataset(tmp_path):
    """lerobot-train's DataLoader workers are spawned: a fresh interpreter that only unpickles the dataset must
    end up with the grouped query (and read the same item)."""
    import pickle
    import subprocess
    import sys
    from pathlib import Path

    ds = _tiny_goal_dataset(tmp_path)
    expected = ds[2]
    (tmp_path / "ds.pkl").write_bytes(pickle.dumps(ds))
    code = (
        "import pickle, sys, torch\n"
        "from lerobot.datasets.dataset_reader import DatasetReader\n"
        "before = DatasetReader._query_hf_dataset.__name__\n"
        "ds = pickle.loads(open(sys.argv[1], 'rb').read())\n"
        "item = ds[2]\n"
        "torch.save({k: v for k, v in item.items() if torch.is_tensor(v)}, sys.argv[2])\n"
        "print(before, DatasetReader._query_hf_dataset.__name__)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "ds.pkl"), str(tmp_path / "item.pt")],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert out.stdout.split()[-2:] == ["_query_hf_dataset", "_grouped_query_hf_dataset"], out.stdout
    item = torch.load(tmp_path / "item.pt")
    for key, value in item.items():
        assert torch.equal(value, expected[key]), key


def test_torchcodec_warning_is_one_line(caplog):
    import logging

    import sigma_policy  # noqa: F401  (installs the patches)

    logger = logging.getLogger("lerobot.utils.import_utils")
    with caplog.at_level(logging.WARNING, logger="lerobot.utils.import_utils"):
        logger.warning(
            "Could not load libtorchcodec.\n[start of libtorchcodec loading traceback]\n...\n"
            "'torchcodec' is installed but cannot be loaded (see the error above). Falling back to 'pyav'."
        )
        logger.warning("an unrelated warning\nwith two lines")
    messages = [r.getMessage() for r in caplog.records]
    assert messages[0].startswith("torchcodec cannot load here") and "\n" not in messages[0]
    assert messages[1] == "an unrelated warning\nwith two lines"


def test_importing_sigma_policy_changes_nothing_in_lerobot():
    """``import sigma_policy`` only registers names; the plugin entry point LeRobot loads installs the fix."""
    import subprocess
    import sys

    code = (
        "from lerobot.datasets.dataset_reader import DatasetReader as R; original = R._query_hf_dataset\n"
        "import sigma_policy\n"
        "assert R._query_hf_dataset is original, 'import sigma_policy patched LeRobot'\n"
        "import lerobot_policy_sigma\n"
        "assert R._query_hf_dataset is not original, 'the plugin entry point did not install the fix'\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
