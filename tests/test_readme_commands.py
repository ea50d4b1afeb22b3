"""Every command README.md, RESULTS.md and docs/ print parses as printed.

Each ``sigma-*``, ``lerobot-train``/``lerobot-eval``, ``python -m benchmarks.*`` and ``make`` command in
README.md (code blocks and inline code) is parsed by the same draccus config class its entry point parses it
with, so a renamed or removed option, a wrong value type or a positional argument the CLI does not take fails
here. Placeholders (``DIR``, ``CKPT``) are fine where the option is a path. The commands' behaviour is tested in
the modules' own tests; running them all here would take hours.
"""

from __future__ import annotations

import dataclasses
import importlib
import re
import shlex
from collections.abc import Callable
from pathlib import Path

import draccus
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("README.md", "RESULTS.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")))
PROGRAMS = ("sigma-data", "sigma-eval", "sigma-viz", "sigma-demo", "sigma-ablate", "sigma-results")
PROGRAMS += (
    "sigma-diagnose",
    "sigma-compare",
    "sigma-diff",
    "sigma-encode",
    "lerobot-train",
    "lerobot-eval",
    "python -m benchmarks.",
    "make ",
)


def _from_markdown(text: str) -> list[str]:
    """Commands in fenced blocks (continuation lines joined, comments dropped), in table cells that start with
    one (a cell's later ``import ...`` spans are ``sigma-data import`` forms) and ``make`` spans in prose."""
    commands = []
    blocks = re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M)
    for block in blocks:
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" # ")[0].strip()
            if line.startswith(PROGRAMS):
                commands.append(line)
    prose = re.sub(r"^```[^\n]*\n.*?^```", "", text, flags=re.S | re.M)
    for line in prose.splitlines():
        if line.startswith("|"):
            for cell in line.strip("|").split("|"):
                spans = re.findall(r"`([^`]+)`", cell)
                if spans and cell.strip().startswith("`") and spans[0].startswith(PROGRAMS):
                    commands.append(spans[0])
                    if spans[0].startswith("sigma-data import"):
                        commands += [f"sigma-data {s}" for s in spans[1:] if s.startswith("import ")]
        commands += re.findall(r"`(make [^`]+)`", line)
    return list(dict.fromkeys(commands))


def _commands() -> list[str]:
    return [c for doc in DOCS for c in _from_markdown((ROOT / doc).read_text())]


def _parse(config_class: type, args: list[str]) -> None:
    draccus.parse(config_class=config_class, args=args)


def _sigma_data(args: list[str]) -> None:
    from sigma_data.cli import COMMANDS

    command, rest = args[0], args[1:]
    assert command in COMMANDS, f"sigma-data has no command {command!r}"
    if command == "collect":
        from sigma_data.collect import CollectConfig

        _parse(CollectConfig, rest)
    elif command == "validate":
        from sigma_data.validate import ValidateConfig

        _parse(ValidateConfig, rest)
    else:
        from sigma_data.importers.hdf5 import Hdf5ImportConfig
        from sigma_data.importers.raw import RawImportConfig
        from sigma_data.importers.teleop import TeleopConfig

        source = {"hdf5": Hdf5ImportConfig, "raw": RawImportConfig, "teleop": TeleopConfig}
        assert rest and rest[0] in source, f"sigma-data import needs one of {sorted(source)}, got {rest[:1]}"
        _parse(source[rest[0]], rest[1:])


def _pipeline(module: str, name: str) -> Callable[[list[str]], None]:
    return lambda args: _parse(getattr(importlib.import_module(module), name), args)


def _sigma_viz(args: list[str]) -> None:
    from pipelines.viz.cli import EpisodeViewConfig, PolicyViewConfig

    views = {"episode": EpisodeViewConfig, "policy": PolicyViewConfig}
    assert args and args[0] in views, f"sigma-viz needs one of {sorted(views)}, got {args[:1]}"
    _parse(views[args[0]], args[1:])


def _lerobot(config: str) -> Callable[[list[str]], None]:
    def parse(args: list[str]) -> None:
        import lerobot.envs
        import lerobot.policies  # noqa: F401  (the stock policy types)
        from lerobot.utils.import_utils import register_third_party_plugins

        import sigma_data.lerobot_env  # noqa: F401  (the sigma_robosuite env type)

        register_third_party_plugins()
        module, name = config.rsplit(".", 1)
        # ``--policy.path`` is LeRobot's own flag: its parser loads the checkpoint's config before draccus runs,
        # and the other ``--policy.*`` options then override that config (their names depend on its type).
        if any(a.startswith("--policy.path") for a in args):
            args = [a for a in args if not a.startswith("--policy.")]
        _parse(getattr(importlib.import_module(module), name), args)

    return parse


def _benchmark(module: str, args: list[str]) -> None:
    mod = importlib.import_module(module)
    configs = [
        obj
        for name, obj in vars(mod).items()
        if name.endswith("Config") and dataclasses.is_dataclass(obj) and obj.__module__ == mod.__name__
    ]
    assert len(configs) == 1, (
        f"{module}: expected one *Config dataclass, found {[c.__name__ for c in configs]}"
    )
    _parse(configs[0], args)


def _make(args: list[str]) -> None:
    targets = set(re.findall(r"^([a-z][\w-]*):", (ROOT / "Makefile").read_text(), flags=re.M))
    assert args[0] in targets, f"Makefile has no target {args[0]!r} (has {sorted(targets)})"
    extra = [a.removeprefix("ARGS=") for a in args[1:] if a.startswith("ARGS=")]
    if args[0] == "demo" and extra:
        from pipelines.demo import DemoConfig

        _parse(DemoConfig, shlex.split(extra[0]))


PARSERS: dict[str, Callable[[list[str]], None]] = {
    "sigma-data": _sigma_data,
    "sigma-eval": _pipeline("pipelines.evaluate", "EvalConfig"),
    "sigma-demo": _pipeline("pipelines.demo", "DemoConfig"),
    "sigma-ablate": _pipeline("pipelines.ablation", "AblationConfig"),
    "sigma-results": _pipeline("pipelines.results", "ResultsConfig"),
    "sigma-diagnose": _pipeline("pipelines.diagnostics", "DiagnoseConfig"),
    "sigma-compare": _pipeline("pipelines.compare", "CompareConfig"),
    "sigma-diff": lambda args: importlib.import_module("pipelines.paired").parse_args(args),
    "sigma-encode": _pipeline("pipelines.encode", "EncodeConfig"),
    "sigma-viz": _sigma_viz,
    "lerobot-train": _lerobot("lerobot.configs.train.TrainPipelineConfig"),
    "lerobot-eval": _lerobot("lerobot.configs.eval.EvalPipelineConfig"),
    "make": _make,
}


def test_the_readme_prints_commands():
    commands = _commands()
    programs = {shlex.split(c)[0] for c in commands}
    assert len(commands) > 20 and {"sigma-data", "sigma-eval", "lerobot-train", "make"} <= programs


@pytest.mark.parametrize("command", _commands())
def test_readme_command_parses(command, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    words = shlex.split(command)
    if words[:2] == ["python", "-m"]:
        _benchmark(words[2], words[3:])
        return
    assert words[0] in PARSERS, f"no parser registered for {words[0]!r}: add it to PARSERS"
    try:
        PARSERS[words[0]](words[1:])
    except SystemExit as exc:  # draccus/argparse print the reason to stderr
        pytest.fail(f"{command!r} does not parse (exit {exc.code}); see the captured stderr")


def test_a_wrong_option_is_caught():
    with pytest.raises(SystemExit):
        PARSERS["sigma-eval"](["--checkpoint", "CKPT", "--no_such_option", "1"])
    with pytest.raises(AssertionError, match="no command"):
        PARSERS["sigma-data"](["valdate", "--root=DIR"])
