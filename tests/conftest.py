"""Shared pytest set-up: offline hubs and headless MuJoCo before anything imports robosuite."""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TOKENIZERS_PARALLELISM", "false")

import sigma_data  # noqa: F401  (chooses MUJOCO_GL before robosuite/mujoco are imported)
