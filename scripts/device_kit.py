"""Run the whole suite benchmark on a lent GPU machine that has no network: pack here, run there, unpack here.

The GPU machine (docs/gpu.md "A GPU lease in one call") has Python 3.12, PyTorch, CUDA and many common packages,
but not LeRobot, robosuite, MuJoCo, sigma or the text encoder's weights, and it reaches no network. What travels to
it is the working tree and a few ignored folders, 64 MiB in all; what comes back is at most 8 files of 16 MiB. The
suite's datasets (about 50 KB a keyframe) are too large to carry, so the machine collects them itself.

``pack`` (here) writes ``.device/``:

* ``site.tar.xz``: the installed distributions the machine lacks (:data:`CARRIED`), copied from this environment:
  LeRobot and the pure-Python packages it imports; MuJoCo and robosuite, robosuite with only the meshes and
  textures the five tasks open (``scripts/robosuite_assets.txt``, 84 of its 824 data files); PyAV with its FFmpeg
  (28 MB of the archive: LeRobot checks its video encoders whenever it creates a dataset, even one without video);
  and sigma built as a wheel. The machine unpacks it onto ``PYTHONPATH``; nothing is downloaded or built there.
* ``text_features.safetensors``: every registered task's instruction features (``sigma-encode``), so the 88 MB
  text encoder stays here (``SIGMA_TEXT_FEATURES``, sigma_policy/text_encoder.py).
* ``gl/``: the EGL and OpenGL loader packages (Debian, amd64) MuJoCo's offscreen rendering needs there.

``scripts/device_suite.sh`` (there) runs ``bench_suite`` (collection, training, diagnosis, closed loop) and returns
the results and each run's last checkpoint. ``unpack`` (here) puts them into a ``bench_suite`` output folder, where
``bench_suite --device cpu`` with the same options prints the table again and ``sigma-eval`` can score the
checkpoints with test-time options.

    python scripts/device_kit.py --command pack
    # the device call, twice in a row if the first returns "still running": carry ['.device'], command
    #   bash scripts/device_suite.sh --wait 560 -- --preset gpu --episodes 30 \
    #     --tasks '[lift,stack,pick_place,nut_assembly,door]'
    python scripts/device_kit.py --command unpack --parts /work/.device/<call>/files --output_dir outputs/suite_h200
"""

from __future__ import annotations

import importlib.metadata as metadata
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import draccus

ROOT = Path(__file__).resolve().parents[1]
KIT = ROOT / ".device"
PARTS_PREFIX = "runs.tar.part-"
ASSETS = Path(__file__).with_name("robosuite_assets.txt")
DATA_SUFFIXES = (".obj", ".stl", ".STL", ".msh", ".png", ".jpg", ".mtl", ".urdf", ".dae", ".ply")

# The Python distributions the GPU machine's image holds (Python 3.12; as its operators listed them on 2026-11-17,
# docs/gpu.md).
_DEVICE_IMAGE_NAMES = """
absl-py accelerate aiofiles aiohappyeyeballs aiohttp aiosignal annotated-doc anyio attrs botorch build certifi
charset-normalizer chex click cloudpickle cmake colorama contourpy coverage cuda-bindings cuda-core
cuda-pathfinder cuda-toolkit cupy-cuda13x cycler cython diffrax e3nn einops equinox etils execnet filelock
flatbuffers flax fonttools formulaic frozenlist fsspec gpytorch grpcio h11 h5py hf-xet httpcore httpx
huggingface-hub humanize hypothesis idna imageio iniconfig interface-meta jax jax-cuda13-pjrt jax-cuda13-plugin
jaxlib jaxtyping jinja2 joblib kiwisolver lazy-loader lightning lightning-utilities linear-operator lineax
llvmlite lxml markdown markdown-it-py markupsafe matplotlib mdurl meson ml-dtypes mpi4py mpmath msgpack
multidict multipledispatch mypy-extensions nanobind narwhals networkx ninja numba numba-cuda numpy numpyro
nvidia-cublas nvidia-cuda-cupti nvidia-cuda-nvrtc nvidia-cuda-runtime nvidia-cudnn-cu13 nvidia-cufft
nvidia-cufile nvidia-curand nvidia-cusolver nvidia-cusparse nvidia-cusparselt-cu13 nvidia-ml-py nvidia-nccl-cu13
nvidia-nvjitlink nvidia-nvshmem-cu13 nvidia-nvtx onnx onnx-ir onnxruntime onnxscript opencv-python-headless
optax opt-einsum opt-einsum-fx optimistix orbax-checkpoint packaging pandas pathspec patsy peft pillow pip
pluggy portalocker prometheus-client propcache protobuf psutil pyarrow pybind11 py-cpuinfo pygments pyparsing
pyproject-hooks pyre-extensions pytest pytest-benchmark pytest-cov pytest-mock pytest-timeout pytest-xdist
python-dateutil pytorch-lightning pyyaml regex requests rich sacrebleu safetensors scikit-build-core
scikit-image scikit-learn scipy seaborn sentencepiece sentence-transformers setuptools shellingham simplejson
six sortedcontainers statsmodels sympy tabulate tensorboard tensorboard-data-server tensorstore threadpoolctl
tifffile tiktoken timm tokenizers toolz torch torchaudio torchdiffeq torch-geometric torchmetrics torchvision
tqdm transformers treescope triton typer typing-extensions typing-inspect urllib3 uvloop wadler-lindig werkzeug
wheel wrapt xarray xxhash yarl zipp
"""
DEVICE_IMAGE = tuple(_DEVICE_IMAGE_NAMES.split())

# Distributions bench_suite imports (collection, lerobot-train, sigma-diagnose, sigma-eval) that the GPU machine's
# image does not hold (DEVICE_IMAGE). Found by running the suite with only the image's packages and these on the path
# (tests/scripts/test_device_kit.py does so).
CARRIED = (
    "lerobot",
    "draccus",
    "datasets",
    "multiprocess",
    "dill",
    "gymnasium",
    "farama-notifications",
    "jsonlines",
    "termcolor",
    "mergedeep",
    "toml",
    "pytz",
    "tzdata",
    "mujoco",
    "robosuite",
    "pyopengl",
    "glfw",
    "av",
)
# Top-level folders some distributions ship beside their package (draccus: its tests and examples); never carried,
# since on the machine they would shadow the checkout's own.
NOT_CARRIED = ("tests", "examples", "docs", "benchmarks")
GL_PACKAGES = ("libvulkan1", "libegl1", "libglvnd0", "libopengl0", "libgl1", "libglx0", "libgles2")


@dataclass
class KitConfig:
    # `pack` (here: write .device/) or `unpack` (here: put what a device call returned into --output_dir).
    command: str = "pack"
    # pack: where the kit goes (scripts/device_suite.sh reads $KIT, default .device), and whether to download the
    # GL loader packages (apt-get; the machine needs them unless its image has EGL).
    kit: Path = KIT
    gl: bool = True
    # unpack: the folder holding the returned parts (runs.tar.part-aa, ...), and the bench_suite output folder.
    parts: Path | None = None
    output_dir: Path | None = None


def _robosuite_assets() -> set[str]:
    return {line for line in ASSETS.read_text().splitlines() if line and not line.startswith("#")}


def _copy_distribution(name: str, site: Path) -> int:
    """Copy the installed files of distribution ``name`` (its RECORD) under ``site``; robosuite's meshes and
    textures only where ``scripts/robosuite_assets.txt`` lists them. Returns the bytes copied."""
    try:
        dist = metadata.distribution(name)
    except metadata.PackageNotFoundError:
        raise ValueError(f"distribution {name!r} is not installed here; run `make setup` first") from None
    assets = _robosuite_assets() if name == "robosuite" else None
    size = 0
    for f in dist.files or []:
        src = Path(dist.locate_file(f))
        if f.parts[0] in ("..", *NOT_CARRIED) or not src.is_file() or src.suffix == ".pyc":
            continue  # console scripts live outside site-packages; bytecode is rebuilt there
        if assets is not None and f.suffix in DATA_SUFFIXES and str(f) not in assets:
            continue
        dst = site / f
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
        size += src.stat().st_size
    if assets is not None:
        missing = sorted(a for a in assets if not (site / a).is_file())
        if missing:
            raise ValueError(
                f"{ASSETS}: {len(missing)} listed files are not in this robosuite, e.g. {missing[0]}"
            )
    return size


def _sigma_wheel(site: Path) -> None:
    """Build sigma's wheel from this checkout (no network, no build isolation) and unpack it under ``site``."""
    build_existed = (ROOT / "build").exists()
    with tempfile.TemporaryDirectory() as tmp:
        pip = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", tmp]
        subprocess.run([*pip, str(ROOT)], check=True)
        (wheel,) = Path(tmp).glob("lerobot_policy_sigma-*.whl")
        with zipfile.ZipFile(wheel) as z:
            z.extractall(site)
    if not build_existed:  # setuptools' staging copy of the checkout
        shutil.rmtree(ROOT / "build", ignore_errors=True)


def _gl_packages(dest: Path) -> None:
    """Download the amd64 EGL/OpenGL loader packages with apt (the recipe of the device's own notes)."""
    lists = Path(tempfile.mkdtemp()) / "lists"
    (lists / "partial").mkdir(parents=True)
    opts = ["-oAPT::Architecture=amd64", "-oAPT::Architectures=amd64", f"-oDir::State::Lists={lists}"]
    dest.mkdir(parents=True)
    subprocess.run(["apt-get", *opts, "-qq", "update"], check=True)
    subprocess.run(["apt-get", *opts, "-qq", "download", *GL_PACKAGES], check=True, cwd=dest)


def pack(cfg: KitConfig) -> int:
    kit = cfg.kit
    if kit.exists() and any(kit.iterdir()) and not (kit / "site.tar.xz").exists():
        raise ValueError(f"{kit} holds files but no kit (site.tar.xz): choose a new or empty --kit folder")
    if kit.exists():
        shutil.rmtree(kit)
    kit.mkdir(parents=True)
    with tempfile.TemporaryDirectory() as tmp:
        site = Path(tmp) / "site"
        installed = sum(_copy_distribution(name, site) for name in CARRIED)
        _sigma_wheel(site)
        with tarfile.open(kit / "site.tar.xz", "w:xz", preset=6) as tar:
            tar.add(site, arcname="site")
    from pipelines.encode import main as encode

    if encode(["--output", str(kit / "text_features.safetensors")]) != 0:
        raise RuntimeError("sigma-encode failed")
    if cfg.gl:
        _gl_packages(kit / "gl")
    total = sum(p.stat().st_size for p in kit.rglob("*") if p.is_file())
    print(
        f"device_kit: {kit} is {total / 2**20:.1f} MiB ({len(CARRIED)} distributions, {installed / 2**20:.0f} MiB "
        f"installed, sigma, text features, {len(GL_PACKAGES) if cfg.gl else 0} GL packages); with the working tree "
        "it must stay under the 64 MiB a device call carries"
    )
    return 0


def unpack(cfg: KitConfig) -> int:
    if cfg.parts is None or cfg.output_dir is None:
        raise ValueError("unpack needs --parts (the returned files) and --output_dir (a bench_suite folder)")
    parts = sorted(cfg.parts.glob(PARTS_PREFIX + "*"))
    if not parts:
        raise ValueError(f"{cfg.parts}: no {PARTS_PREFIX}* files")
    with tempfile.TemporaryDirectory() as tmp:
        joined = Path(tmp) / "runs.tar"
        with open(joined, "wb") as out:
            for part in parts:
                out.write(part.read_bytes())
        with tarfile.open(joined) as tar:
            names = tar.getnames()
            if not names or any(n.split("/")[0] not in ("runs", "logs") for n in names):
                raise ValueError(f"{cfg.parts}: the parts do not hold a bench_suite runs/ folder")
            tar.extractall(cfg.output_dir, filter="tar")
    runs = sorted({n.split("/")[1] for n in names if n.startswith("runs/") and n.count("/") >= 1})
    for run in runs:  # the machine's paths, as this machine's (sigma-diagnose and sigma-eval read them)
        checkpoints = cfg.output_dir / "runs" / run / "train" / "checkpoints"
        for config in checkpoints.glob("*/pretrained_model/train_config.json"):
            saved = json.loads(config.read_text())
            saved["dataset"]["root"] = str(cfg.output_dir / "train" / "data" / "keyframe")
            saved["output_dir"] = str(cfg.output_dir / "runs" / run / "train")
            config.write_text(json.dumps(saved, indent=4))
    print(f"device_kit: {len(parts)} parts -> {cfg.output_dir}: {', '.join(runs)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    cfg = draccus.parse(KitConfig, args=sys.argv[1:] if argv is None else argv)
    try:
        if cfg.command == "pack":
            return pack(cfg)
        if cfg.command == "unpack":
            return unpack(cfg)
        raise ValueError(f"--command must be pack or unpack, got {cfg.command!r}")
    except ValueError as e:
        print(f"device_kit: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
