"""``sigma-data``: command-line entry point with sub-commands (draccus dataclass configs, like LeRobot).

    sigma-data collect --tasks=lift,stack --episodes=50 --workers=2 --output_dir=outputs/sigma_data
    sigma-data collect --tasks=all --cameras=agentview,robot0_eye_in_hand --height=84 --width=84
    sigma-data validate --root=outputs/sigma_data/keyframe

``sigma-data <command> --help`` lists every option of a command.
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


COMMANDS: dict[str, tuple[Callable[[Sequence[str]], int], str]] = {
    "collect": (_collect, "record scripted-expert episodes into dense and keyframe LeRobot datasets"),
    "validate": (_validate, "check a dataset against the sigma data contract"),
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
    except (ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"sigma-data {command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
