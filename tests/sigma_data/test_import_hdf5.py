"""robosuite demo.hdf5 (made by robosuite's own DataCollectionWrapper + gather_demonstrations_as_hdf5) and a
robomimic-layout file import by state replay into datasets that pass validation and load in stock LeRobot;
bad files and bad demos give errors naming file, demo and field, and the good demos still convert."""

import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

# robosuite.wrappers before any render context exists (see the lead's note on late imports).
from robosuite.controllers import load_composite_controller_config
from robosuite.scripts.collect_human_demonstrations import gather_demonstrations_as_hdf5
from robosuite.wrappers import DataCollectionWrapper

from sigma_data.cameras import RenderOptions
from sigma_data.cli import main as cli_main
from sigma_data.control import EnvDriver
from sigma_data.importers import REPORT, SourceError
from sigma_data.importers.hdf5 import Hdf5ImportConfig, import_hdf5
from sigma_data.importers.model_files import foreign_files
from sigma_data.output import OutputConfig
from sigma_data.suite import get_task, make_env, reset_env
from sigma_data.validate import ValidateConfig, validate_dataset

CAMERAS = "agentview,robot0_eye_in_hand"
SEEDS = (0, 1)


class TrackingWrapper(DataCollectionWrapper):
    """robosuite's wrapper, also noting the true grip-site position before every step (independent check)."""

    def __init__(self, env, directory):
        super().__init__(env, directory)
        self.tracks: list[list[np.ndarray]] = []

    def reset(self):
        out = super().reset()
        self.tracks.append([])
        return out

    def step(self, action):
        self.env.sim.forward()
        site = self.env.robots[0].eef_site_id["right"]
        self.tracks[-1].append(np.array(self.env.sim.data.site_xpos[site]))
        return super().step(action)


@pytest.fixture(scope="module")
def robosuite_hdf5(tmp_path_factory):
    """demo.hdf5 of 2 Lift demos by the sigma expert (~80 steps each), and the true eef track of each."""
    root = tmp_path_factory.mktemp("robosuite_demos")
    task = get_task("lift")
    variation = task.variations[0]
    env = make_env(task)
    wrapper = TrackingWrapper(env, str(root / "raw"))
    for seed in SEEDS:
        reset_env(wrapper, task, variation, seed)
        task.expert(EnvDriver(wrapper), variation, np.random.default_rng(seed))
        assert task.success(env, variation)
    wrapper.close()  # flushes the last episode
    tracks = [np.stack(t) for t in wrapper.tracks if t]
    env_info = json.dumps(
        {
            "env_name": "Lift",
            "robots": "Panda",
            "controller_configs": env.robots[0].composite_controller_config,
        }
    )
    gather_demonstrations_as_hdf5(str(root / "raw"), str(root), env_info)
    return root / "demo.hdf5", tracks


def write_robomimic(path: Path, demos: list[dict], env_name: str = "Lift", masks: dict | None = None) -> Path:
    """A robomimic-layout file (docs/robosuite.md §8.2): env_args, demo_0.., num_samples, rewards/dones, mask/."""
    controller = load_composite_controller_config(controller="BASIC", robot="Panda")
    env_args = {
        "env_name": env_name,
        "env_version": "1.5.1",
        "type": 1,
        "env_kwargs": {"robots": ["Panda"], "controller_configs": controller, "control_freq": 20},
    }
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps(env_args)
        data.attrs["total"] = sum(len(d.get("actions", [])) for d in demos)
        for i, demo in enumerate(demos):
            grp = data.create_group(f"demo_{i}")
            grp.attrs["model_file"] = demo["model_file"]
            grp.attrs["num_samples"] = len(demo["actions"])
            for key in ("states", "actions"):
                if key in demo:
                    grp.create_dataset(key, data=demo[key])
            grp.create_dataset("rewards", data=np.zeros(len(demo["actions"])))
            grp.create_dataset("dones", data=np.zeros(len(demo["actions"]), dtype=np.int64))
        for key, names in (masks or {}).items():
            f.create_dataset(f"mask/{key}", data=np.array([n.encode() for n in names]))
    return path


def robosuite_demos(path: Path) -> list[dict]:
    with h5py.File(path, "r") as f:
        names = sorted(f["data"], key=lambda n: int(n.split("_")[1]))
        return [
            {
                "model_file": f["data"][n].attrs["model_file"],
                "states": f["data"][n]["states"][()],
                "actions": f["data"][n]["actions"][()],
            }
            for n in names
        ]


def hdf5_config(path: Path, out: Path, **kw) -> Hdf5ImportConfig:
    output = kw.pop("output", OutputConfig(dir=out, dense_video=False))
    render = RenderOptions(cameras=CAMERAS, height=32, width=32)
    return Hdf5ImportConfig(path=path, output=output, render=render, progress=False, **kw)


def assert_valid(root: Path) -> LeRobotDataset:
    report = validate_dataset(ValidateConfig(root=root, frames_per_episode=3))
    assert report.num_errors == 0, report.table()
    return LeRobotDataset("local/imported", root=root, depth_output_unit="m", video_backend="pyav")


def test_robosuite_demo_hdf5_imports_by_state_replay(robosuite_hdf5, tmp_path):
    path, tracks = robosuite_hdf5
    out = tmp_path / "out"
    output = OutputConfig(dir=out)  # default storage: video dense, image keyframe
    summary = import_hdf5(hdf5_config(path, out, output=output))
    assert summary.converted == 2 and not summary.failed, summary.failed
    dense = assert_valid(out / "dense")
    keyframe = assert_valid(out / "keyframe")
    assert dense.meta.total_episodes == 2 and keyframe.meta.total_episodes == 2
    item = dense[0]
    assert item["task"] == "lift the cube"
    assert item["observation.images.agentview"].shape == (3, 32, 32)
    assert item["observation.images.agentview_depth"].shape == (1, 32, 32)
    assert keyframe[0]["action"].shape == (9,)

    cols = dense.hf_dataset.with_format(None).select_columns(
        ["episode_index", "observation.state", "action"]
    )[:]
    eps, states = np.asarray(cols["episode_index"]), np.asarray(cols["observation.state"])
    actions = np.asarray(cols["action"])
    demos = robosuite_demos(path)
    for ep in range(2):
        s, a = states[eps == ep], actions[eps == ep]
        demo = demos[ep]
        assert len(s) == len(demo["states"])
        np.testing.assert_allclose(a, demo["actions"], atol=1e-6)  # recorded actions, untouched
        # gripper_open from the commanded grip of the previous step
        np.testing.assert_array_equal(s[1:, 7], (demo["actions"][:-1, -1] < 0).astype(np.float32))
        # replayed grip-site positions = the true positions seen while recording (demo order is listdir's)
        track = next(t for t in tracks if len(t) == len(s))  # one position before each recorded action
        np.testing.assert_allclose(s[:, :3], track, atol=1e-5)
    side = json.loads((out / "keyframe" / "meta" / "sigma.json").read_text())
    assert side["layout"] == "robosuite" and side["env_name"] == "Lift"
    assert {e["provenance"]["demo"] for e in side["episodes"]} == {"demo_1", "demo_2"}
    assert "import hdf5: converted 2, failed 0" in summary.line()


def test_robomimic_layout_with_filter_key(robosuite_hdf5, tmp_path):
    path, _ = robosuite_hdf5
    demos = robosuite_demos(path)
    rm = write_robomimic(tmp_path / "low_dim.hdf5", demos, masks={"train": ["demo_0"], "valid": ["demo_1"]})
    out = tmp_path / "out"
    summary = import_hdf5(hdf5_config(rm, out, filter_key="valid", instruction="raise the red block"))
    assert summary.converted == 1 and not summary.failed
    ds = assert_valid(out / "keyframe")
    assert_valid(out / "dense")
    assert ds[0]["task"] == "raise the red block"
    side = json.loads((out / "dense" / "meta" / "sigma.json").read_text())
    assert side["layout"] == "robomimic" and side["filter_key"] == "valid"
    assert [e["provenance"]["demo"] for e in side["episodes"]] == ["demo_1"]
    assert side["episodes"][0]["length"] == len(demos[1]["states"])
    with pytest.raises(SourceError, match=r"low_dim\.hdf5: mask/test: no such filter key.*'train', 'valid'"):
        import_hdf5(hdf5_config(rm, tmp_path / "out2", filter_key="test"))


def test_bad_demos_fail_alone_and_earlier_output_survives(robosuite_hdf5, tmp_path):
    path, _ = robosuite_hdf5
    full = robosuite_demos(path)[0]
    good = {**full, "states": full["states"][:30], "actions": full["actions"][:30]}  # short is enough here
    no_states = {k: v for k, v in good.items() if k != "states"}
    nan_states = {**good, "states": good["states"].copy()}
    nan_states["states"][5, 3] = np.nan
    wrong_width = {**good, "states": good["states"][:, :-2]}
    bad_model = {**good, "model_file": "<mujoco><worldbody><body"}
    scrambled = {**good, "states": good["states"].copy()}
    scrambled["states"][10, 1 + 7] = 6.6e31  # a finger joint (qpos[7]): finite garbage
    demos = [good, bad_model, no_states, nan_states, wrong_width, scrambled, good, good]
    rm = write_robomimic(tmp_path / "mixed.hdf5", demos)
    out = tmp_path / "out"
    summary = import_hdf5(hdf5_config(rm, out, max_episodes=7))  # the 8th demo is left out
    assert summary.converted == 2 and len(summary.failed) == 5
    errors = {f.episode.split(": ")[-1]: f.error for f in summary.failed}
    assert "mixed.hdf5: demo_1: attrs['model_file']: the model does not load" in errors["demo_1"]
    assert errors["demo_2"].endswith("mixed.hdf5: demo_2: states: missing dataset")
    assert "mixed.hdf5: demo_3: states: NaN or inf in 1 row(s), first at row 5" in errors["demo_3"]
    assert (
        "demo_4: states: rows have 30 values but the model's state [time, qpos, qvel] has 32"
        in errors["demo_4"]
    )
    assert "mixed.hdf5: demo_5: states: row 10 replays to finger joints" in errors["demo_5"]
    assert "failed 5" in summary.line()
    report = json.loads((out / REPORT).read_text())
    assert report["converted"] == 2 and len(report["failed"]) == 5
    assert assert_valid(out / "keyframe").meta.total_episodes == 2
    # Importing again into the same place is refused before anything is touched.
    with pytest.raises(FileExistsError):
        import_hdf5(hdf5_config(rm, out))
    assert LeRobotDataset("local/x", root=out / "dense", video_backend="pyav").meta.total_episodes == 2


def test_bad_files_are_named(robosuite_hdf5, tmp_path):
    path, _ = robosuite_hdf5
    truncated = tmp_path / "truncated.hdf5"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(SourceError, match=r"truncated\.hdf5: cannot open as HDF5"):
        import_hdf5(hdf5_config(truncated, tmp_path / "o1"))
    assert cli_main(["import", "hdf5", f"--path={truncated}", f"--output.dir={tmp_path / 'o1'}"]) == 1
    garbage = tmp_path / "garbage.hdf5"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(SourceError, match=r"garbage\.hdf5: cannot open as HDF5"):
        import_hdf5(hdf5_config(garbage, tmp_path / "o2"))
    unknown = write_robomimic(tmp_path / "unknown.hdf5", robosuite_demos(path)[:1], env_name="LiftTheMoon")
    with pytest.raises(
        SourceError,
        match=r"unknown\.hdf5: data\.attrs\['env_args'\]\.env_name: unknown robosuite environment",
    ):
        import_hdf5(hdf5_config(unknown, tmp_path / "o3"))
    wipe = write_robomimic(tmp_path / "wipe.hdf5", robosuite_demos(path)[:1], env_name="Wipe")
    with pytest.raises(SourceError, match=r"no sigma task maps robosuite environment 'Wipe'.*--instruction"):
        import_hdf5(hdf5_config(wipe, tmp_path / "o4"))
    for out in ("o1", "o2", "o3", "o4"):
        assert not (tmp_path / out / "dense").exists()


def test_model_files_that_read_outside_robosuite_are_refused(robosuite_hdf5, tmp_path):
    """A demo MJCF that points MuJoCo at other local files (an include, an absolute mesh path, a path climbing out
    of robosuite's package) is refused with the file, demo and field named; trusted files skip the check."""
    path, _ = robosuite_hdf5
    good = robosuite_demos(path)[0]
    xml = good["model_file"]
    xml = xml.decode() if isinstance(xml, bytes) else str(xml)
    assert foreign_files(xml) == [], "robosuite's own demo reads only robosuite's assets"
    secret = tmp_path / "secret.xml"
    secret.write_text("<mujoco/>")
    head, rest = xml.split(">", 1)
    include = f'{head}><include file="{secret}"/>{rest}'
    mesh_file = re.search(r'<mesh [^>]*file="([^"]+)"', xml).group(1)
    escape = xml.replace(mesh_file, "/anywhere/robosuite/../../../../etc/hostname", 1)
    absolute = xml.replace(mesh_file, str(secret), 1)
    assert foreign_files(include) == [f"<include file='{secret}'>"]
    assert len(foreign_files(absolute)) == 1
    elsewhere = "<mujoco><compiler meshdir='/etc'/><asset><mesh name='m' file='hostname'/></asset></mujoco>"
    assert foreign_files(elsewhere) == ["<mesh file='hostname'>"]
    with pytest.raises(ValueError, match="not valid XML"):
        foreign_files("<mujoco><body")

    short = {**good, "states": good["states"][:20], "actions": good["actions"][:20]}
    demos = [short] + [{**short, "model_file": m} for m in (include, escape, absolute)]
    rm = write_robomimic(tmp_path / "crafted.hdf5", demos)
    summary = import_hdf5(hdf5_config(rm, tmp_path / "out"))
    assert summary.converted == 1 and len(summary.failed) == 3
    for failure in summary.failed:
        assert "crafted.hdf5" in failure.error and "attrs['model_file']" in failure.error
        assert (
            "reads files outside robosuite's assets" in failure.error
            and "--trust_model_files" in failure.error
        )
    trusted = import_hdf5(hdf5_config(rm, tmp_path / "trusted", trust_model_files=True, max_episodes=2))
    assert trusted.converted + len(trusted.failed) == 2
    assert not any("outside robosuite" in f.error for f in trusted.failed)
