"""Import robosuite ``demo.hdf5`` and robomimic HDF5 demonstrations by **state replay**.

Two layouts are read (docs/robosuite.md §8.1, §8.2), told apart by the attributes of the ``data`` group:

* robosuite (``DataCollectionWrapper`` + ``gather_demonstrations_as_hdf5``): ``data.attrs["env_info"]`` (JSON:
  ``env_name``, ``robots``, ``controller_configs``), demos ``demo_1 .. demo_N``;
* robomimic: ``data.attrs["env_args"]`` (JSON: ``env_name``, ``env_kwargs``), demos ``demo_0 ..``, and filter
  keys ``mask/<key>`` (arrays of demo names), e.g. ``train`` / ``valid``.

Each demo has ``attrs["model_file"]`` (the MJCF of the episode), ``states`` (T, 1 + nq + nv) -- ``states[t]``
is the flattened MuJoCo state ``[time, qpos, qvel]`` *before* ``actions[t]`` -- and ``actions`` (T, 7).

States are the ground truth; actions are never re-executed (open-loop replay drifts by millimetres, docs/robosuite.md §8.3).
Per demo the scene is rebuilt from ``model_file`` (``env.edit_model_xml`` -> ``env.reset_from_xml_string``),
then every state is set (``sim.set_state_from_flattened`` + ``sim.forward``) to read the grip-site pose, finger
joints and arm joint velocities, and the chosen cameras are re-rendered with metric depth and calibration
(:class:`~sigma_data.cameras.CameraRig`), which those files never had. The episode keeps the file's T frames
and recorded actions (the last frame's action is the one recorded there, not a hold). ``gripper_open`` comes
from the commanded grip (``actions[t - 1, -1] < 0``; frame 0 open); keyframes from the ARM/PerAct heuristic on
the replayed arm joint velocities and that gripper state (``ignore_collision`` is unknown for imported demos
and stored as 0). The instruction is the sigma task's canonical instruction for the robosuite environment
(:data:`ENV_TASKS`) or ``--instruction``.

A file that cannot be opened, or whose environment is unknown, stops the import with an error naming the file
and field; a bad demo (missing ``states``, NaN states, a model that does not load, ...) is reported as failed
and the other demos still convert.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from sigma_data.cameras import CameraRig, RenderConfig, RenderOptions, check_cameras
from sigma_data.contract import DENSE_ACTION_DIM, STATE_DIM, implausible_state
from sigma_data.dataset_layout import DatasetLayout
from sigma_data.episode import Episode, Keyframe, gripper_open_from_actions
from sigma_data.importers import (
    DatasetSink,
    ImportSummary,
    OutputError,
    SourceError,
    finite_or_error,
)
from sigma_data.importers.model_files import foreign_files
from sigma_data.keyframes import dedup_by_pose, discover_keyframes
from sigma_data.output import OutputConfig
from sigma_data.record import arm_joint_velocities, robot_state

Layout = Literal["robosuite", "robomimic"]

# robosuite environment name -> (sigma task, variation) whose canonical instruction names the demo's goal.
ENV_TASKS: dict[str, tuple[str, str]] = {
    "Lift": ("lift", "lift_cube"),
    "Stack": ("stack", "red_on_green"),  # robosuite's Stack: cubeA (red) on cubeB (green)
    "PickPlaceMilk": ("pick_place", "milk"),
    "PickPlaceBread": ("pick_place", "bread"),
    "PickPlaceCereal": ("pick_place", "cereal"),
    "PickPlaceCan": ("pick_place", "can"),
    "NutAssemblySquare": ("nut_assembly", "square_nut"),
    "NutAssemblyRound": ("nut_assembly", "round_nut"),
    "Door": ("door", "open_door"),
}
ACTION_DIM = DENSE_ACTION_DIM  # robosuite OSC_POSE delta + gripper


@dataclass
class Hdf5ImportConfig:
    """Options of ``sigma-data import hdf5``."""

    # The robosuite demo.hdf5 or robomimic .hdf5 file.
    path: Path | None = None
    # Where and how the datasets are written.
    output: OutputConfig = field(default_factory=OutputConfig)
    # The cameras to render, their image size, the fast exact settings and the depth clip.
    render: RenderOptions = field(default_factory=RenderOptions)
    # robomimic filter key (mask/<key>, e.g. train, valid); None = every demo.
    filter_key: str | None = None
    # Convert at most this many demos (in numeric order); None = all.
    max_episodes: int | None = None
    # The instruction of every demo; None = the sigma task's canonical instruction for the environment.
    instruction: str | None = None
    # Extra keyframe filter: drop a keyframe whose next one has the same gripper state and nearly the same
    # pose (1 cm / 5 deg, docs/robosuite.md §7.2).
    dedup_keyframes: bool = False
    # Let a demo's MJCF read files outside robosuite's assets (includes, meshes, textures elsewhere). Off: such a
    # demo is refused, since a crafted file could render any readable file into the dataset. Only for your own.
    trust_model_files: bool = False
    # Show a progress bar.
    progress: bool = True


@dataclass
class Hdf5Source:
    """File-level facts of an HDF5 demo file."""

    path: Path
    layout: Layout
    env_name: str
    env_kwargs: dict[str, Any]  # kwargs to rebuild the env (robots, controller_configs, ...)
    demos: list[str]  # demo group names to convert, in numeric order
    attrs_field: str  # where env_name came from, for error messages


@dataclass
class DemoArrays:
    """One demo as stored: the episode's MJCF, states (T, D) float64, actions (T, 7) float64."""

    name: str
    model_file: str
    states: np.ndarray
    actions: np.ndarray


def _demo_number(path: Path, name: str) -> int:
    try:
        return int(name.split("_", 1)[1])
    except (IndexError, ValueError):
        raise SourceError(path, name, None, "demo groups must be named demo_<number>") from None


def _json_attr(path: Path, attrs: Any, key: str) -> dict[str, Any]:
    raw = attrs[key]
    try:
        out = json.loads(raw.decode() if isinstance(raw, bytes) else raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SourceError(path, None, f"data.attrs['{key}']", f"not valid JSON ({exc})") from None
    if not isinstance(out, dict):
        raise SourceError(path, None, f"data.attrs['{key}']", "must be a JSON object")
    return out


def open_hdf5(path: Path) -> Any:
    """Open ``path`` read-only; a missing, truncated or corrupt file raises ``ValueError`` naming it."""
    import h5py

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise SourceError(
            path, None, None, f"cannot open as HDF5 (truncated or corrupt file?): {exc}"
        ) from None


def read_source(f: Any, path: Path, filter_key: str | None = None) -> Hdf5Source:
    """Layout, environment and the demo names (filtered by ``mask/<filter_key>``) of an open HDF5 file."""
    if "data" not in f:
        raise SourceError(path, None, "data", "no 'data' group: not a robosuite/robomimic demo file")
    attrs = f["data"].attrs
    if "env_args" in attrs:
        layout: Layout = "robomimic"
        env_args = _json_attr(path, attrs, "env_args")
        env_name = env_args.get("env_name")
        env_kwargs = dict(env_args.get("env_kwargs") or {})
        attrs_field = "data.attrs['env_args'].env_name"
    elif "env_info" in attrs:
        layout = "robosuite"
        env_info = _json_attr(path, attrs, "env_info")
        env_name = env_info.get("env_name") or attrs.get("env")
        env_kwargs = {k: v for k, v in env_info.items() if k != "env_name"}
        attrs_field = "data.attrs['env_info'].env_name"
    else:
        raise SourceError(
            path, None, "data.attrs", "neither 'env_args' (robomimic) nor 'env_info' (robosuite) is present"
        )
    if isinstance(env_name, bytes):
        env_name = env_name.decode()
    if not env_name:
        raise SourceError(path, None, attrs_field, "missing environment name")

    names = sorted((n for n in f["data"] if n.startswith("demo")), key=lambda n: _demo_number(path, n))
    if filter_key is not None:
        masks = f.get("mask")
        if masks is None or filter_key not in masks:
            known = sorted(masks) if masks is not None else []
            raise SourceError(
                path,
                None,
                f"mask/{filter_key}",
                f"no such filter key; the file has: {known or 'no mask group'}",
            )
        wanted = [n.decode() if isinstance(n, bytes) else str(n) for n in masks[filter_key][:]]
        missing = sorted(set(wanted) - set(names))
        if missing:
            raise SourceError(path, None, f"mask/{filter_key}", f"names demos not in data/: {missing}")
        names = [n for n in names if n in set(wanted)]
    if not names:
        raise SourceError(
            path, None, "data", "no demo_<n> groups" + (f" in mask/{filter_key}" if filter_key else "")
        )
    return Hdf5Source(path, layout, str(env_name), env_kwargs, names, attrs_field)


def read_demo(f: Any, source: Hdf5Source, name: str) -> DemoArrays:
    """Read and check one demo's fields; raises :class:`SourceError` naming the demo and field."""
    path = source.path
    grp = f["data"][name]
    if "model_file" not in grp.attrs:
        raise SourceError(
            path, name, "attrs['model_file']", "missing (the episode's MJCF is needed to replay it)"
        )
    model_file = grp.attrs["model_file"]
    model_file = model_file.decode() if isinstance(model_file, bytes) else str(model_file)
    arrays = {}
    for key in ("states", "actions"):
        if key not in grp:
            raise SourceError(path, name, key, "missing dataset")
        try:
            arrays[key] = np.asarray(grp[key][()], dtype=np.float64)
        except (OSError, ValueError, TypeError) as exc:
            raise SourceError(path, name, key, f"cannot read: {exc}") from None
    states, actions = arrays["states"], arrays["actions"]
    if states.ndim != 2 or len(states) < 2:
        raise SourceError(path, name, "states", f"must be (T >= 2, 1 + nq + nv), got shape {states.shape}")
    if actions.shape != (len(states), ACTION_DIM):
        raise SourceError(
            path,
            name,
            "actions",
            f"must be (T, {ACTION_DIM}) with T = {len(states)} states, got {actions.shape}",
        )
    finite_or_error(states, path, name, "states")
    finite_or_error(actions, path, name, "actions")
    return DemoArrays(name, model_file, states, actions)


def check_environment(source: Hdf5Source) -> None:
    """Raise :class:`SourceError` naming the file and field if robosuite has no such environment."""
    from robosuite.environments.base import REGISTERED_ENVS

    if source.env_name not in REGISTERED_ENVS:
        raise SourceError(
            source.path,
            None,
            source.attrs_field,
            f"unknown robosuite environment '{source.env_name}'; known: {', '.join(sorted(REGISTERED_ENVS))}",
        )


def make_replay_env(source: Hdf5Source, render: RenderConfig) -> Any:
    """A robosuite env of the file's environment, robots and controller, with an offscreen renderer and no
    camera observations (rendering is done by :class:`CameraRig`)."""
    import robosuite as suite

    from sigma_data.mujoco_gl import quiet_robosuite

    quiet_robosuite()
    check_environment(source)
    kwargs = dict(source.env_kwargs)
    for key in ("env_name", "type", "env_version"):
        kwargs.pop(key, None)
    kwargs.update(
        has_renderer=False,
        has_offscreen_renderer=True,
        use_camera_obs=False,
        ignore_done=True,
        hard_reset=False,
        camera_names=list(render.cameras),
        camera_heights=render.height,
        camera_widths=render.width,
        camera_depths=True,
    )
    try:
        return suite.make(source.env_name, **kwargs)
    except Exception as exc:
        field = (
            "data.attrs['env_args'].env_kwargs" if source.layout == "robomimic" else "data.attrs['env_info']"
        )
        raise SourceError(source.path, None, field, f"cannot build '{source.env_name}': {exc}") from exc


def instruction_for(source: Hdf5Source, instruction: str | None) -> tuple[str, str, str]:
    """(task, variation, instruction) of the file's demos: the user's instruction, else the task mapping."""
    from sigma_data.suite import get_task, get_variation

    mapped = ENV_TASKS.get(source.env_name)
    if instruction is not None:
        if not instruction.strip():
            raise ValueError("--instruction is empty")
        task, variation = mapped if mapped else (source.env_name, "imported")
        return task, variation, instruction.strip()
    if mapped is None:
        raise SourceError(
            source.path,
            None,
            source.attrs_field,
            f"no sigma task maps robosuite environment '{source.env_name}' to an instruction "
            f"(mapped: {', '.join(sorted(ENV_TASKS))}); pass --instruction",
        )
    task = get_task(mapped[0])
    return task.name, mapped[1], get_variation(task, mapped[1]).instruction


def load_demo_model(
    env: Any, demo: DemoArrays, path: Path, cameras: Sequence[str], trust_model_files: bool = False
) -> None:
    """Rebuild ``env``'s scene from the demo's MJCF and check the state size and cameras. A model that reads files
    outside robosuite's assets is refused unless ``trust_model_files`` (:mod:`sigma_data.importers.model_files`)."""
    try:
        xml = env.edit_model_xml(demo.model_file)
        foreign = [] if trust_model_files else foreign_files(xml)
    except Exception as exc:
        raise SourceError(path, demo.name, "attrs['model_file']", f"the model does not load: {exc}") from exc
    if foreign:
        raise SourceError(
            path,
            demo.name,
            "attrs['model_file']",
            f"reads files outside robosuite's assets: {', '.join(foreign[:3])}"
            f"{f' (+{len(foreign) - 3} more)' if len(foreign) > 3 else ''}; refused "
            "(--trust_model_files=true imports it if you trust this file)",
        )
    try:
        env.reset_from_xml_string(xml)
        env.sim.reset()
    except Exception as exc:
        raise SourceError(path, demo.name, "attrs['model_file']", f"the model does not load: {exc}") from exc
    expected = len(env.sim.get_state().flatten())
    if demo.states.shape[1] != expected:
        raise SourceError(
            path,
            demo.name,
            "states",
            f"rows have {demo.states.shape[1]} values but the model's state [time, qpos, qvel] has {expected}",
        )
    try:
        check_cameras(env, cameras)
    except ValueError as exc:
        raise SourceError(path, demo.name, "attrs['model_file']", str(exc)) from None


def replay_episode(
    env: Any,
    demo: DemoArrays,
    task: str,
    variation: str,
    instruction: str,
    dedup: bool = False,
    provenance: dict[str, Any] | None = None,
    path: Path | None = None,
) -> Episode:
    """Set every stored state (no action is executed) and build the episode with heuristic keyframes.

    The env must hold the demo's model (:func:`load_demo_model`); ``path`` (the source file) names errors.
    """
    gripper_open = gripper_open_from_actions(demo.actions, initial_open=True)
    states = np.empty((len(demo.states), STATE_DIM), dtype=np.float32)
    joint_vel = []
    sim = env.sim
    for t, flat in enumerate(demo.states):
        sim.set_state_from_flattened(flat)
        sim.forward()
        s = robot_state(env, bool(gripper_open[t]))
        if s.shape != (STATE_DIM,):
            raise ValueError(
                f"robot state has {s.shape} values, the contract needs {STATE_DIM} (two fingers)"
            )
        problem = implausible_state(s)
        if problem:
            raise SourceError(
                path or Path("<hdf5>"),
                demo.name,
                "states",
                f"row {t} replays to {problem}: not a robot state",
            )
        states[t] = s
        joint_vel.append(arm_joint_velocities(env))
    joint_vel = np.stack(joint_vel)
    indices = discover_keyframes(joint_vel, gripper_open)
    if dedup:
        indices = dedup_by_pose(indices, states[:, :7], gripper_open)
    keyframes = [Keyframe(i, bool(gripper_open[i]), False, source="heuristic") for i in indices]
    return Episode(
        task=task,
        variation=variation,
        instruction=instruction,
        states=states,
        actions=demo.actions.astype(np.float32),
        keyframes=keyframes,
        joint_velocities=joint_vel,
        sim_states=demo.states,
        provenance=dict(provenance or {}),
    )


def _convert_demo(
    env: Any,
    demo: DemoArrays,
    source: Hdf5Source,
    naming: tuple[str, str, str],
    cfg: Hdf5ImportConfig,
    sink: DatasetSink,
    layout: DatasetLayout,
) -> None:
    """Rebuild, replay, render and write one demo.

    Everything holding the scene's render context (the rig, the frame cache) lives only in this call: robosuite
    frees an EGL context with ``eglReleaseThread`` and ``mjr_freeContext`` in whatever context is current, so an
    old context that outlives :func:`load_demo_model` (and is garbage-collected later) corrupts the new one's
    renders (NaN depth). Freed here, the old context goes with its scene, before the next one is built.
    """
    from sigma_data.replay_render import RenderedFrames

    render = cfg.render.config()
    load_demo_model(env, demo, source.path, render.cameras, cfg.trust_model_files)
    ep = replay_episode(
        env,
        demo,
        *naming,
        dedup=cfg.dedup_keyframes,
        provenance={"importer": "hdf5", "file": str(source.path), "demo": demo.name},
        path=source.path,
    )
    rig = CameraRig(env, render)  # its renders make this scene's context current
    sink.open(layout, rig.static_calibration())
    sink.add(ep, RenderedFrames(ep, rig, keep=sink.shared_frames(ep)), layout)


def import_hdf5(cfg: Hdf5ImportConfig) -> ImportSummary:
    """Convert the demos of ``cfg.path`` into the datasets under ``cfg.output.dir``; returns the summary."""
    from tqdm import tqdm

    from sigma_data.suite import close_env

    if cfg.path is None:
        raise ValueError("--path is required (the .hdf5 file to import)")
    if cfg.max_episodes is not None and cfg.max_episodes < 1:
        raise ValueError(f"max_episodes must be >= 1, got {cfg.max_episodes}")
    path = Path(cfg.path)
    render = cfg.render.config()
    cfg.output.check_writable()
    with open_hdf5(path) as f:
        source = read_source(f, path, cfg.filter_key)
        demos = source.demos[: cfg.max_episodes] if cfg.max_episodes else source.demos
        check_environment(source)
        task, variation, instruction = instruction_for(source, cfg.instruction)
        env = make_replay_env(source, render)
        provenance = {
            "source": f"{source.layout} HDF5 (sigma_data.importers.hdf5)",
            "file": str(path.resolve()),
            "layout": source.layout,
            "env_name": source.env_name,
            "env_kwargs": source.env_kwargs,
            "filter_key": cfg.filter_key,
            "render": asdict(render),
            "keyframes": "ARM heuristic on replayed arm joint velocities, gripper from commands"
            + (" + pose dedup" if cfg.dedup_keyframes else ""),
            "final_action": "as recorded (the file drops the state after the last action)",
        }
        layout = DatasetLayout(render.cameras, render.height, render.width)
        try:
            with DatasetSink(cfg.output, "hdf5", provenance) as sink:
                for name in tqdm(demos, desc=f"import {path.name}", unit="demo", disable=not cfg.progress):
                    try:
                        demo = read_demo(f, source, name)
                        _convert_demo(env, demo, source, (task, variation, instruction), cfg, sink, layout)
                    except OutputError:
                        raise  # the output, not this episode: every later one would fail too
                    except Exception as exc:
                        error = (
                            exc if isinstance(exc, SourceError) else SourceError(path, name, None, repr(exc))
                        )
                        sink.fail(f"{path}: {name}", error)
        finally:
            close_env(env)
    return sink.summary
