"""``scripts/device_kit.py``: what it carries to a GPU machine builds every task there, and what comes back unpacks.

The whole round trip (pack, ``scripts/device_suite.sh`` in an environment holding only the GPU machine's packages
and the kit, unpack) is the slow test; the default suite checks the two pieces most likely to drift: robosuite cut
down to the listed meshes and textures still builds and renders every task's scene, and returned parts unpack
into a run whose configs point at this machine.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

from tests.scripts.script_module import load_script

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "device_kit.py"


kit = load_script("device_kit")

BUILD_EVERY_TASK = """
import numpy as np, robosuite, sigma_data
from sigma_data.suite import TASKS, make_env, reset_env
assert robosuite.__file__.startswith({site!r}), robosuite.__file__
for task in TASKS.values():
    env = make_env(task, cameras=("agentview",), height=32, width=32)
    reset_env(env, task, task.variations[0], seed=0)
    image = env.sim.render(camera_name="agentview", height=32, width=32)
    assert image.std() > 0, task.name
    env.close()
print("built", len(TASKS))
"""


def test_robosuite_cut_to_the_listed_assets_builds_every_task(tmp_path: Path) -> None:
    site = tmp_path / "site"
    kit._copy_distribution("robosuite", site)
    data = [p for p in (site / "robosuite").rglob("*") if p.suffix in kit.DATA_SUFFIXES]
    assert len(data) == len(kit._robosuite_assets()) < 100  # of robosuite's 824 meshes and textures
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run(
        [sys.executable, "-c", BUILD_EVERY_TASK.format(site=str(site))],
        capture_output=True, text=True, cwd=ROOT, env=env, timeout=600,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    assert "built 5" in out.stdout


def test_a_listed_asset_robosuite_lacks_is_refused(tmp_path: Path, monkeypatch) -> None:
    listed = tmp_path / "assets.txt"
    listed.write_text("# header\nrobosuite/models/assets/objects/meshes/not_a_mesh.stl\n")
    monkeypatch.setattr(kit, "ASSETS", listed)
    with pytest.raises(
        ValueError, match=r"assets\.txt: 1 listed files are not in this robosuite, e\.g\. .*not_a_mesh"
    ):
        kit._copy_distribution("robosuite", tmp_path / "site")


def _returned_parts(folder: Path, run: str) -> None:
    """What scripts/device_suite.sh returns: a tar of logs/ and runs/, split in parts."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:

        def add(name: str, text: str) -> None:
            data = text.encode() + b" " * 40_000  # large enough for two parts of 32 KB
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))

        saved = {"dataset": {"root": ".device/suite/train/data/keyframe"}, "output_dir": ".device/suite/x"}
        add(f"runs/{run}/train/checkpoints/003000/pretrained_model/train_config.json", json.dumps(saved))
        add(f"runs/{run}/eval/results.json", "{}")
        add("logs/run_0.log", "done")
        link = tarfile.TarInfo(f"runs/{run}/train/checkpoints/last")
        link.type, link.linkname = tarfile.SYMTYPE, "003000"
        tar.addfile(link)
    blob = buf.getvalue()
    folder.mkdir()
    for i in range(0, len(blob), 32_768):
        (folder / f"{kit.PARTS_PREFIX}a{chr(ord('a') + i // 32_768)}").write_bytes(blob[i : i + 32_768])


def test_unpack_joins_the_parts_and_points_the_configs_here(tmp_path: Path, capsys) -> None:
    run = "seed0_decay3000_lr0.003_batch64_gpu"
    _returned_parts(tmp_path / "files", run)
    assert len(list((tmp_path / "files").iterdir())) >= 2
    out = tmp_path / "suite"
    assert (
        kit.main(["--command", "unpack", "--parts", str(tmp_path / "files"), "--output_dir", str(out)]) == 0
    )
    config = out / "runs" / run / "train" / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    saved = json.loads(config.read_text())
    assert saved["dataset"]["root"] == str(out / "train" / "data" / "keyframe")
    assert saved["output_dir"] == str(out / "runs" / run / "train")
    assert (out / "logs" / "run_0.log").read_text().startswith("done")
    assert f"-> {out}: {run}" in capsys.readouterr().out
    assert kit.main(["--command", "unpack", "--parts", str(tmp_path), "--output_dir", str(out)]) == 1
    assert "no runs.tar.part-* files" in capsys.readouterr().err


def test_pack_refuses_a_folder_that_is_not_a_kit(tmp_path: Path, capsys) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    assert kit.main(["--command", "pack", "--kit", str(tmp_path), "--gl", "false"]) == 1
    assert "holds files but no kit" in capsys.readouterr().err and (tmp_path / "notes.txt").exists()


PYTHON_WITHOUT_SITE = '#!/bin/sh\nexec {python} -S "$@"\n'


@pytest.mark.slow
def test_the_suite_runs_where_only_the_gpu_image_and_the_kit_are_installed(tmp_path: Path) -> None:
    """The round trip on this CPU: pack a kit; run scripts/device_suite.sh with python3 seeing only the GPU image's
    distributions (those installed here, linked into a folder of their own) and the kit, as the machine would
    (collection, training, closed loop and diagnosis of a tiny Lift run, over two calls, with a `--final` call
    between them that returns what the unfinished pipeline has so far); unpack what each returned.

    ``SIGMA_IMAGE_VERSIONS`` may name a folder of the image's own versions of the shared distributions (installed
    with ``pip install --target``; docs/gpu.md), put before this environment's on the path."""
    import importlib.metadata as metadata

    image = tmp_path / "image"
    image.mkdir()
    for name in kit.DEVICE_IMAGE:
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue  # not installed here: sigma does not import it
        for top in {f.parts[0] for f in dist.files or [] if f.parts[0] != ".."}:
            src, dst = Path(dist.locate_file(top)), image / top
            if src.exists() and not dst.exists():
                dst.symlink_to(src)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "python3").write_text(
        PYTHON_WITHOUT_SITE.format(python=Path(sys.base_prefix) / "bin" / "python3.12")
    )
    (bin_dir / "python3").chmod(0o755)
    pack = tmp_path / "kit"
    assert kit.main(["--command", "pack", "--kit", str(pack), "--gl", "false"]) == 0
    out = tmp_path / "out"
    out.mkdir()
    env = {
        "PATH": f"{bin_dir}:/usr/bin:/bin:/usr/sbin:/sbin", "HOME": str(tmp_path), "OUT": str(out),
        "PYTHONPATH": os.pathsep.join(filter(None, [os.environ.get("SIGMA_IMAGE_VERSIONS"), str(image)])),
        "KIT": str(pack), "STATE": str(tmp_path / "state"),
    }  # fmt: skip
    suite = [
        "--tasks",
        "[lift]",
        "--episodes",
        "2",
        "--heldout_episodes",
        "1",
        "--steps",
        "4",
        "--batch_size",
        "2",
    ]
    suite += [
        "--checkpoints",
        "1",
        "--eval_episodes",
        "1",
        "--max_keyframes",
        "4",
        "--device",
        "cpu",
        "--workers",
        "1",
    ]
    script = [str(ROOT / "scripts" / "device_suite.sh")]
    first = subprocess.run(
        ["bash", *script, "--wait", "5", "--", *suite], env=env, capture_output=True, text=True
    )
    assert first.returncode == 0 and "still running" in first.stdout, first.stdout + first.stderr
    # A lease's last call (--final) returns what the unfinished pipeline has written so far: here, its logs.
    early = tmp_path / "early"
    early.mkdir()
    partial = subprocess.run(
        ["bash", *script, "--final", "--wait", "1", "--", *suite], env={**env, "OUT": str(early)},
        capture_output=True, text=True,
    )  # fmt: skip
    assert partial.returncode == 0, partial.stdout + partial.stderr
    assert "partial, returned after" in partial.stdout, partial.stdout + partial.stderr
    assert "--final: the pipeline is still running" in (early / "status.txt").read_text()
    so_far = tmp_path / "so_far"
    assert kit.main(["--command", "unpack", "--parts", str(early), "--output_dir", str(so_far)]) == 0
    assert (so_far / "logs" / "collect.log").is_file()
    second = subprocess.run(
        ["bash", *script, "--wait", "900", "--", *suite], env=env, capture_output=True, text=True
    )
    assert second.returncode == 0 and "done (exit 0)" in second.stdout, (out / "status.txt").read_text()
    assert kit.main(["--command", "unpack", "--parts", str(out), "--output_dir", str(tmp_path / "here")]) == 0
    (run,) = (tmp_path / "here" / "runs").iterdir()
    results = json.loads((run / "eval" / "results.json").read_text())
    assert [v["episodes"] for v in results["variations"]] == [1]
    assert (run / "train" / "checkpoints" / "last" / "pretrained_model" / "model.safetensors").is_file()
    assert (run / "train" / "diagnostics" / "diagnostics.json").is_file()
