"""The validation report: options, one result row per check, and the collector the checks write to."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

Status = Literal["ok", "warn", "error", "skip"]


@dataclass
class ValidateConfig:
    """Options of ``sigma-data validate``."""

    # Dataset directory (a LeRobot v3 root: meta/, data/, videos/).
    root: Path
    # Any name; used only as LeRobot's repo_id for a local root.
    repo_id: str = "local/sigma"
    # Where to write the JSON report (default: <root>/meta/sigma_validation.json).
    report: Path | None = None
    # Images decoded per episode for the depth/calibration checks (first, last and evenly spaced ones).
    frames_per_episode: int = 6
    # Plausible metric depth for a tabletop scene, metres.
    depth_range: tuple[float, float] = (0.01, 10.0)
    # Largest tolerated fraction of invalid (<= 0, NaN, inf) depth pixels per camera.
    max_invalid_depth: float = 0.25
    # A dense episode's end effector faster than this between two frames is an error, m/s (a Panda: ~1.7).
    max_eef_speed: float = 3.0
    # A gripper change must have a keyframe within this many frames (dense datasets).
    gripper_tolerance: int = 3
    # Keyframe datasets: |action[i][:3] - pose of frame i+1| must be below this, metres.
    goal_tolerance_m: float = 2e-3
    # Fraction of frames in which the end effector must project inside each fixed camera.
    min_eef_visible: float = 0.9


@dataclass
class CheckResult:
    name: str
    status: Status
    detail: str
    episode: int | None = None
    frame: int | None = None
    field: str | None = None


@dataclass
class ValidationReport:
    root: str
    kind: str
    num_episodes: int
    num_frames: int
    cameras: list[str]
    checks: list[CheckResult] = field(default_factory=list)
    instructions: dict[str, int] = field(default_factory=dict)  # instruction -> number of episodes

    @property
    def num_errors(self) -> int:
        return sum(c.status == "error" for c in self.checks)

    @property
    def num_warnings(self) -> int:
        return sum(c.status == "warn" for c in self.checks)

    def to_json(self) -> dict:
        out = asdict(self)
        out["num_errors"], out["num_warnings"] = self.num_errors, self.num_warnings
        return out

    def table(self) -> str:
        """A plain-text table for people: one row per check."""
        rows = [("check", "status", "where", "detail")]
        for c in self.checks:
            where = " ".join(
                p
                for p in (
                    f"ep {c.episode}" if c.episode is not None else "",
                    f"frame {c.frame}" if c.frame is not None else "",
                    c.field or "",
                )
                if p
            )
            rows.append(
                (c.name, c.status.upper() if c.status in ("error", "warn") else c.status, where, c.detail)
            )
        widths = [max(len(r[i]) for r in rows) for i in range(3)]
        lines = [
            f"{r[0]:<{widths[0]}}  {r[1]:<{widths[1]}}  {r[2]:<{widths[2]}}  {r[3]}".rstrip() for r in rows
        ]
        lines.insert(1, "-" * min(120, sum(widths) + 30))
        return "\n".join(lines)


class Checker:
    """Collects results; one instance per validation run."""

    def __init__(self) -> None:
        self.results: list[CheckResult] = []
        self.row_starts: dict[int, int] = {}  # episode -> its first row in the dataset

    def add(self, name: str, status: Status, detail: str, episode=None, frame=None, field=None) -> None:
        """``frame`` is the frame within ``episode`` (0 = its first frame), not the dataset-wide row."""
        self.results.append(CheckResult(name, status, detail, episode, frame, field))

    def at_row(self, name: str, status: Status, detail: str, episode: int, row: int, field=None) -> None:
        """:meth:`add` for a dataset-wide ``row`` of ``episode``."""
        self.add(name, status, detail, int(episode), int(row) - self.row_starts.get(int(episode), 0), field)
