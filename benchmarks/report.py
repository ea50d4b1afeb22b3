"""Result writing for the benchmarks; lives in :mod:`pipelines.reporting` (installed with the package)."""

from pipelines.reporting import RESULTS_DIR, command_line, machine_description, write_report

__all__ = ["RESULTS_DIR", "command_line", "machine_description", "write_report"]
