"""The grouped multi-frame query returns exactly what LeRobot's own returns, with far fewer decodes."""

from __future__ import annotations

import torch
from lerobot.datasets.dataset_reader import DatasetReader
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from sigma_policy import lerobot_patches
from tests.sigma_policy.tiny_dataset import write_tiny_keyframe_dataset


def test_patched_query_matches_lerobot_original(tmp_path):
    assert lerobot_patches.install()  # installed by `import sigma_policy`; idempotent
    assert DatasetReader._query_hf_dataset is lerobot_patches._grouped_query_hf_dataset
    original = lerobot_patches._grouped_query_hf_dataset.original

    root = write_tiny_keyframe_dataset(tmp_path / "ds")
    ds = LeRobotDataset("local/tiny", root=root, delta_timestamps=None, video_backend="pyav")
    keys = [k for k in ds.features if k.startswith("observation.")]
    ds = LeRobotDataset(
        "local/tiny",
        root=root,
        delta_timestamps={k: [0.0, 1 / ds.fps] for k in keys},
        video_backend="pyav",
    )
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
