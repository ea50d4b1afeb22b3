"""The episode log of an unfinished ``sigma-eval`` run: one JSON line per finished episode, so a killed evaluation
resumes where it stopped and a GPU lease that runs out brings back the episodes it finished (docs/gpu.md).

``<output_dir>/episodes.jsonl`` starts with a header naming what decides an episode's outcome (the policy's
weights by content, the keyframe budget and the test-time options); each later line is one finished episode.
A rerun trusts the logged episodes only under the same header; a line cut short by a kill is skipped. Once the
evaluation has written ``results.json`` the log is removed: a finished evaluation is redone, not resumed.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from sigma_data.files import write_text_atomic

__all__ = ["LOG_NAME", "EpisodeLog"]

LOG_NAME = "episodes.jsonl"
_FORMAT = 1
logger = logging.getLogger(__name__)


class EpisodeLog:
    """Append-only record of finished episodes (dataclasses) under ``output_dir``, keyed by ``header`` (a JSON-able
    dict)."""

    def __init__(self, output_dir: Path, header: dict[str, Any]):
        self.path = Path(output_dir) / LOG_NAME
        self.header = json.loads(json.dumps({"sigma_eval_log": _FORMAT, **header}))  # as a line reads back

    def resume(self, parse: Callable[[dict], Any]) -> list[Any]:
        """The episodes a killed run with the same header finished (``parse`` turns a line's dict into a result),
        then a fresh log holding the header and those episodes. A log under another header is replaced."""
        finished: list[Any] = []
        lines = self.path.read_text().splitlines() if self.path.exists() else []
        if lines:
            try:
                same = json.loads(lines[0]) == self.header
            except json.JSONDecodeError:
                same = False
            if not same:
                logger.warning("%s: written under other weights or options; evaluating afresh", self.path)
            else:
                for number, line in enumerate(lines[1:], start=2):
                    try:
                        finished.append(parse(json.loads(line)))
                    except (json.JSONDecodeError, TypeError) as e:  # cut short by a kill, or not an episode
                        logger.warning("%s:%d: skipped (%s)", self.path, number, e)
        write_text_atomic(
            self.path, "".join(json.dumps(d) + "\n" for d in [self.header, *map(asdict, finished)])
        )
        return finished

    def append(self, result: Any) -> None:
        """Record one finished episode (flushed, so a kill after this call keeps it)."""
        with open(self.path, "a") as f:
            f.write(json.dumps(asdict(result)) + "\n")

    def remove(self) -> None:
        """Drop the log once the evaluation's ``results.json`` is written."""
        self.path.unlink(missing_ok=True)
