"""``sigma-data``: command-line entry point with sub-commands (draccus dataclass configs, like LeRobot).

    sigma-data collect --tasks=lift,stack --episodes=50 --workers=2 --output.dir=outputs/sigma_data
    sigma-data collect --tasks=all --render.cameras=agentview,robot0_eye_in_hand --render.height=84 --render.width=84
    sigma-data validate --root=outputs/sigma_data/keyframe
    sigma-data import hdf5 --path=demo.hdf5 --render.cameras=agentview --render.height=84 --render.width=84
    sigma-data import hdf5 --path=low_dim_v15.hdf5 --filter_key=train --max_episodes=50 --output.dir=outputs/lift_ph
    sigma-data import raw --path=/data/ur5_episodes --output.dir=outputs/real
    sigma-data import teleop --task=lift --device=keyboard --episodes=5 --output.dir=outputs/teleop

``sigma-data <command> --help`` lists every option of a command. ``collect`` and every importer share the
``--output.*`` options (where and how the datasets are written) and, where they render, ``--render.*``.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence

import draccus


def _collect(argv: Sequence[str]) -> int:
    from sigma_data.collect import CollectConfig, collect

    cfg = draccus.parse(config_class=CollectConfig, args=list(argv))
    summary = collect(cfg)
    print(summary.line())
    return 0


def _validate(argv: Sequence[str]) -> int:
    from sigma_data.validate import ValidateConfig, run_validate

    cfg = draccus.parse(config_class=ValidateConfig, args=list(argv))
    return run_validate(cfg)


IMPORT_SOURCES = ("hdf5", "raw", "teleop")


def _import(argv: Sequence[str]) -> int:
    """``sigma-data import hdf5|raw|teleop [--option=value ...]``: one draccus config per source.

    Exit status 0 when every source episode converted, 1 when any failed (the others are still written;
    ``<output.dir>/import.json`` lists the failures).
    """
    if not argv or argv[0] not in IMPORT_SOURCES:
        got = f" '{argv[0]}'" if argv else ""
        raise ValueError(f"import needs a source{got}: one of {', '.join(IMPORT_SOURCES)} (then --help)")
    source, rest = argv[0], list(argv[1:])
    if source == "hdf5":
        from sigma_data.importers.hdf5 import Hdf5ImportConfig, import_hdf5

        summary = import_hdf5(draccus.parse(config_class=Hdf5ImportConfig, args=rest))
    elif source == "raw":
        from sigma_data.importers.raw import RawImportConfig, import_raw

        summary = import_raw(draccus.parse(config_class=RawImportConfig, args=rest))
    else:
        from sigma_data.importers.teleop import TeleopConfig, outcome_line, record_teleop

        summary, outcomes = record_teleop(draccus.parse(config_class=TeleopConfig, args=rest))
        print(outcome_line(outcomes))
    for failure in summary.failed:
        print(f"failed: {failure.error}", file=sys.stderr)
    print(summary.line())
    return 1 if summary.failed else 0


COMMANDS: dict[str, tuple[Callable[[Sequence[str]], int], str]] = {
    "collect": (_collect, "record scripted-expert episodes into dense and keyframe LeRobot datasets"),
    "validate": (_validate, "check a dataset against the sigma data contract"),
    "import": (
        _import,
        "convert robosuite/robomimic HDF5, raw real-robot episodes or teleoperation (hdf5|raw|teleop)",
    ),
}


def _usage() -> str:
    lines = ["usage: sigma-data <command> [--option=value ...]", "", "commands:"]
    lines += [f"  {name:<10} {doc}" for name, (_, doc) in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import sigma_data  # noqa: F401  (headless MuJoCo GL before robosuite)

    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(_usage())
        return 0 if args else 2
    command, rest = args[0], args[1:]
    if command not in COMMANDS:
        print(f"sigma-data: unknown command '{command}'\n\n{_usage()}", file=sys.stderr)
        return 2
    try:
        return COMMANDS[command][0](rest)
    except (ValueError, OSError) as exc:  # bad input, missing or existing paths, a failed write
        print(f"sigma-data {command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
