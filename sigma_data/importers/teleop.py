"""Record demonstrations by teleoperation straight into sigma episodes and datasets.

An operator drives the robot of a registry task with one of robosuite's input devices (keyboard; SpaceMouse
when ``hid`` and the device are present) and, with extra keys, marks keyframes by hand (the paper's real-robot
"drag to keypoints" practice), keeps or discards the episode, or resets it:

==================  ============================================================================
key                 effect
==================  ============================================================================
``k``               mark the current frame as a keyframe
``Enter``           keep the episode (it is written to the datasets) and start the next one
``Backspace``       discard the episode and start the next one
``Ctrl+q`` / ``q``  robosuite's reset: discard and restart this episode (same seed)
``Esc``             stop the session (an unfinished episode is discarded)
==================  ============================================================================

plus robosuite's own motion keys (arrows, ``.``/``;``, ``e r y h p o``, space toggles the gripper).

Two small interfaces make it testable headless, with no keyboard or display:

* :class:`TeleopSource` -- what sigma needs from an input device; robosuite's ``Device`` subclasses
  (``Keyboard``, ``SpaceMouse``) satisfy it as they are: ``start_control()`` and ``input2action()`` (a dict with
  ``right_delta`` (6,) in [-1, 1] and ``right_gripper`` (1,), +1 close / -1 open, or ``None`` when the device
  asks for a reset);
* :class:`EventSource` -- ``poll()`` returns the :class:`TeleopEvent` s since the last tick
  (:class:`KeyEvents` listens to the keys above).

:class:`ScriptedDevice` satisfies both from a list of :class:`ScriptStep` s, for tests and replays.

Episodes are recorded without rendering (:class:`~sigma_data.record.EpisodeRecorder`: sim state every control
step) and rendered by state replay when written, like the scripted collector. Keyframes (``keyframes``):
``manual`` = the marked frames + every commanded gripper change + the last frame; ``heuristic`` = the ARM
heuristic on the arm joint velocities; ``union`` = both. ``ignore_collision`` is not known for teleoperated
motion and is stored as 0.
"""

from __future__ import annotations

import dataclasses
import queue
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from sigma_data.cameras import CameraRig, RenderOptions
from sigma_data.dataset_layout import DatasetLayout
from sigma_data.episode import Episode, Keyframe
from sigma_data.importers import DatasetSink, ImportSummary
from sigma_data.keyframes import discover_keyframes
from sigma_data.output import OutputConfig
from sigma_data.record import EpisodeRecorder

KeyframeMode = Literal["manual", "heuristic", "union"]


class TeleopEvent(StrEnum):
    """Operator commands besides motion."""

    KEYFRAME = "keyframe"  # mark the current frame
    KEEP = "keep"  # end the episode and keep it
    DISCARD = "discard"  # end the episode and drop it
    RESET = "reset"  # drop the episode and restart it from the same initial state
    QUIT = "quit"  # stop the session


@runtime_checkable
class TeleopSource(Protocol):
    """An input device in robosuite's ``Device`` API (robosuite's ``Keyboard``/``SpaceMouse`` satisfy it)."""

    def start_control(self) -> None: ...

    def input2action(self) -> dict[str, Any] | None: ...


@runtime_checkable
class EventSource(Protocol):
    """Operator events since the previous tick."""

    def poll(self) -> list[TeleopEvent]: ...


def device_action(action: dict[str, Any], arm: str = "right") -> np.ndarray:
    """robosuite ``input2action()`` dict -> the 7-D OSC_POSE delta ``[dx, dy, dz, rx, ry, rz, grip]``."""
    try:
        delta = np.asarray(action[f"{arm}_delta"], dtype=np.float64).reshape(-1)
        grip = np.asarray(action[f"{arm}_gripper"], dtype=np.float64).reshape(-1)
    except KeyError as exc:
        raise ValueError(f"device action has no {exc} entry (keys: {sorted(action)})") from None
    if delta.shape != (6,) or grip.shape != (1,):
        raise ValueError(
            f"device action must give a 6-D arm delta and a 1-D gripper, got {delta.shape}, {grip.shape}"
        )
    return np.clip(np.concatenate([delta, grip]), -1.0, 1.0)


# --------------------------------------------------------------------------------------------------
# Devices
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScriptStep:
    """One control tick of a scripted operator: a 7-D action (``None``: no step, e.g. only events) and the
    events issued before it (a keyframe mark applies to the frame reached by the previous tick)."""

    action: Sequence[float] | None = None
    events: tuple[TeleopEvent, ...] = ()


class ScriptedDevice:
    """A :class:`TeleopSource` and :class:`EventSource` playing a fixed script; ``QUIT`` when it runs out.

    Each tick the session calls :meth:`poll` (advances to the next step, returns its events), then, unless an
    event ended the episode, :meth:`input2action` (the step's action; ``None`` actions are skipped).
    """

    def __init__(self, steps: Sequence[ScriptStep]):
        self.steps = list(steps)
        self._i = -1
        self.started = 0  # start_control() calls, i.e. episodes begun

    def start_control(self) -> None:
        self.started += 1

    def poll(self) -> list[TeleopEvent]:
        self._i += 1
        if self._i >= len(self.steps):
            return [TeleopEvent.QUIT]
        return list(self.steps[self._i].events)

    def input2action(self) -> dict[str, Any] | None:
        action = self.steps[self._i].action if 0 <= self._i < len(self.steps) else None
        if action is None:
            return {}
        a = np.asarray(action, dtype=np.float64)
        return {"right_delta": a[:6], "right_gripper": a[6:]}


class KeyEvents:
    """:class:`EventSource` from the keyboard (``pynput``; needs a display): ``k``, Enter, Backspace, Esc."""

    def __init__(self) -> None:
        from pynput.keyboard import Key, Listener  # imported here: pynput needs an X display

        self._key = Key
        self._queue: queue.SimpleQueue[TeleopEvent] = queue.SimpleQueue()
        self._listener = Listener(on_release=self._on_release)
        self._listener.start()

    def _on_release(self, key: Any) -> None:
        named = {self._key.enter: TeleopEvent.KEEP, self._key.backspace: TeleopEvent.DISCARD}
        named[self._key.esc] = TeleopEvent.QUIT
        if key in named:
            self._queue.put(named[key])
        elif getattr(key, "char", None) == "k":
            self._queue.put(TeleopEvent.KEYFRAME)

    def poll(self) -> list[TeleopEvent]:
        out = []
        while not self._queue.empty():
            out.append(self._queue.get())
        return out

    def stop(self) -> None:
        self._listener.stop()


def make_device(
    kind: str, env: Any, pos_sensitivity: float = 1.0, rot_sensitivity: float = 1.0
) -> TeleopSource:
    """robosuite's keyboard or SpaceMouse driver for ``env`` (needs a display / the ``hid`` package)."""
    if kind == "keyboard":
        from robosuite.devices import Keyboard

        return Keyboard(env=env, pos_sensitivity=pos_sensitivity, rot_sensitivity=rot_sensitivity)
    if kind == "spacemouse":
        from robosuite.devices.spacemouse import SpaceMouse

        return SpaceMouse(env=env, pos_sensitivity=pos_sensitivity, rot_sensitivity=rot_sensitivity)
    raise ValueError(f"unknown device '{kind}' (keyboard | spacemouse)")


# --------------------------------------------------------------------------------------------------
# Session
# --------------------------------------------------------------------------------------------------


@dataclass
class EpisodeOutcome:
    """How one teleoperated episode ended: ``keep`` (with its episode), ``discard``, ``reset``, ``timeout``
    or ``quit``; ``steps`` control steps were recorded."""

    kind: str
    steps: int
    seed: int
    episode: Episode | None = None
    marks: list[int] = field(default_factory=list)


def teleop_keyframes(
    marks: Sequence[int], gripper_open: np.ndarray, joint_velocities: np.ndarray, mode: KeyframeMode
) -> list[Keyframe]:
    """Keyframes of a teleoperated episode (see the module docstring for the modes)."""
    g = np.asarray(gripper_open).astype(bool)
    T = len(g)
    sources: dict[int, str] = {}
    if mode in ("heuristic", "union"):
        sources.update(dict.fromkeys(discover_keyframes(joint_velocities, g), "heuristic"))
    if mode in ("manual", "union"):
        sources.update({t: "gripper" for t in range(1, T) if g[t] != g[t - 1]})
        sources.update({t: "manual" for t in marks if 0 < t < T})
    if mode not in ("manual", "heuristic", "union"):
        raise ValueError(f"unknown keyframe mode '{mode}' (manual | heuristic | union)")
    sources.setdefault(T - 1, "final")
    return [Keyframe(t, bool(g[t]), False, source=sources[t]) for t in sorted(sources)]


class TeleopSession:
    """Runs teleoperated episodes on ``env`` (a registry task's env) from ``device`` and ``events``.

    ``reset`` puts the env in the initial state of a seed (default: the registry's ``reset_env``: seeded
    placement, gripper opened); ``on_step`` runs after each control step (e.g. ``env.render`` for a viewer).
    """

    def __init__(
        self,
        env: Any,
        task: Any,
        variation: Any,
        device: TeleopSource,
        events: EventSource,
        keyframes: KeyframeMode = "manual",
        max_steps: int = 2000,
        on_step: Callable[[], None] | None = None,
        reset: Callable[[int], None] | None = None,
    ):
        from sigma_data.suite import reset_env

        self.env, self.task, self.variation = env, task, variation
        self.device, self.events = device, events
        self.keyframes, self.max_steps, self.on_step = keyframes, max_steps, on_step
        self.reset = reset or (lambda seed: reset_env(env, task, variation, seed))

    def run_episode(self, seed: int) -> EpisodeOutcome:
        """Record one episode from the initial state of ``seed`` until the operator ends it."""
        self.reset(seed)
        self.device.start_control()
        recorder = EpisodeRecorder(self.env)
        marks: list[int] = []
        while True:
            for event in self.events.poll():
                if event is TeleopEvent.KEYFRAME:
                    if recorder.num_steps > 0 and (not marks or marks[-1] != recorder.num_steps):
                        marks.append(recorder.num_steps)  # the frame reached by the last step
                elif event is TeleopEvent.KEEP:
                    if recorder.num_steps == 0:
                        return EpisodeOutcome("discard", 0, seed, marks=marks)  # nothing to keep
                    return EpisodeOutcome(
                        "keep", recorder.num_steps, seed, self._episode(recorder, marks, seed), marks
                    )
                else:  # DISCARD, RESET, QUIT
                    return EpisodeOutcome(event.value, recorder.num_steps, seed, marks=marks)
            action = self.device.input2action()
            if action is None:  # the device's own reset (robosuite keyboard: Ctrl+q)
                return EpisodeOutcome(TeleopEvent.RESET.value, recorder.num_steps, seed, marks=marks)
            if not action:
                continue
            recorder.step(device_action(action))
            if self.on_step is not None:
                self.on_step()
            if recorder.num_steps >= self.max_steps:
                return EpisodeOutcome("timeout", recorder.num_steps, seed, marks=marks)

    def _episode(self, recorder: EpisodeRecorder, marks: list[int], seed: int) -> Episode:
        ep = recorder.to_episode(
            self.task.name,
            self.variation.name,
            self.variation.instruction,
            seed,
            provenance={"importer": "teleop", "keyframe_mode": self.keyframes, "manual_marks": list(marks)},
        )
        keyframes = teleop_keyframes(marks, ep.states[:, 7], ep.joint_velocities, self.keyframes)
        return dataclasses.replace(ep, keyframes=keyframes)

    def run(
        self, episodes: int, start_seed: int = 0, on_keep: Callable[[Episode], None] | None = None
    ) -> list[EpisodeOutcome]:
        """Record until ``episodes`` are kept or the operator quits. A reset repeats the seed; keep/discard/
        timeout move on to the next seed. ``on_keep`` receives each kept episode (e.g. to write it)."""
        outcomes: list[EpisodeOutcome] = []
        seed = start_seed
        while sum(o.kind == "keep" for o in outcomes) < episodes:
            outcome = self.run_episode(seed)
            outcomes.append(outcome)
            if outcome.kind == "quit":
                break
            if outcome.kind == "keep" and on_keep is not None:
                on_keep(outcome.episode)
            if outcome.kind != "reset":
                seed += 1
        return outcomes


# --------------------------------------------------------------------------------------------------
# CLI entry
# --------------------------------------------------------------------------------------------------


@dataclass
class TeleopOutputConfig(OutputConfig):
    """Where and how ``sigma-data import teleop`` writes its datasets."""

    # Where the datasets go.
    dir: Path = Path("outputs/sigma_teleop")


@dataclass
class TeleopConfig:
    """Options of ``sigma-data import teleop``."""

    # Registry task.
    task: str = "lift"
    # Variation of the task (None = its first variation).
    variation: str | None = None
    # robosuite input device: "keyboard" or "spacemouse".
    device: str = "keyboard"
    # Scale of the device's translation commands.
    pos_sensitivity: float = 1.0
    # Scale of the device's rotation commands.
    rot_sensitivity: float = 1.0
    # Stop after this many kept episodes (or Esc).
    episodes: int = 10
    # Seed of the first episode's scene (then +1 per episode).
    start_seed: int = 0
    # Control steps before an episode times out (and is discarded).
    max_steps: int = 2000
    # Keyframes: "manual" (marks + gripper changes + last), "heuristic" (ARM), or "union".
    keyframes: str = "manual"
    # Show robosuite's on-screen viewer (needs a display).
    viewer: bool = True
    # The cameras rendered into the datasets, their image size, the fast exact settings and the depth clip.
    render: RenderOptions = field(default_factory=RenderOptions)
    # Where and how the datasets are written.
    output: TeleopOutputConfig = field(default_factory=TeleopOutputConfig)

    def __post_init__(self) -> None:
        if self.device not in ("keyboard", "spacemouse"):
            raise ValueError(f"--device must be keyboard or spacemouse, got {self.device!r}")
        if self.keyframes not in ("manual", "heuristic", "union"):
            raise ValueError(f"--keyframes must be manual, heuristic or union, got {self.keyframes!r}")


def outcome_line(outcomes: Sequence[EpisodeOutcome]) -> str:
    """``teleop: kept 3, discarded 1, reset 2, timed out 0 episodes``."""
    count = {k: sum(o.kind == k for o in outcomes) for k in ("keep", "discard", "reset", "timeout")}
    return (
        f"teleop: kept {count['keep']}, discarded {count['discard']}, reset {count['reset']}, "
        f"timed out {count['timeout']} episodes"
    )


def record_teleop(
    cfg: TeleopConfig, device: TeleopSource | None = None, events: EventSource | None = None
) -> tuple[ImportSummary, list[EpisodeOutcome]]:
    """Run a teleoperation session and write the kept episodes; devices default to ``cfg.device`` + keys."""
    from sigma_data.replay_render import RenderedFrames
    from sigma_data.suite import close_env, get_task, get_variation, make_env

    task = get_task(cfg.task)
    variation = get_variation(task, cfg.variation) if cfg.variation else task.variations[0]
    render = cfg.render.config()
    cfg.output.check_writable()
    env = make_env(task, cameras=render.cameras, height=render.height, width=render.width)
    on_step = None
    if cfg.viewer:
        env.has_renderer = True  # robosuite opens its viewer at the next reset
        on_step = env.render
    key_events = None
    try:
        if device is None:
            device = make_device(cfg.device, env, cfg.pos_sensitivity, cfg.rot_sensitivity)
        if events is None:
            events = key_events = KeyEvents()
        rig = CameraRig(env, render)
        layout = DatasetLayout(render.cameras, render.height, render.width)
        provenance = {
            "source": f"teleoperation with robosuite {cfg.device} (sigma_data.importers.teleop)",
            "env_name": task.env_name,
            "env_kwargs": dict(task.env_kwargs),
            "bounds": list(task.bounds),
            "render": dataclasses.asdict(render),
            "keyframes": cfg.keyframes,
        }
        with DatasetSink(cfg.output, "teleop", provenance) as sink:

            def write(ep: Episode) -> None:
                sink.open(layout, rig.static_calibration())
                sink.add(ep, RenderedFrames(ep, rig, keep=sink.shared_frames(ep)), layout)

            session = TeleopSession(
                env, task, variation, device, events, cfg.keyframes, cfg.max_steps, on_step
            )
            outcomes = session.run(cfg.episodes, cfg.start_seed, on_keep=write)
    finally:
        if key_events is not None:
            key_events.stop()
        close_env(env)
    return sink.summary, outcomes
