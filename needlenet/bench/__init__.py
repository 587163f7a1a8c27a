"""Benchmarks: ``needlenet bench SUITE``. Each suite measures on seeded data, with classical
and learned features through the same back ends, and reports figures with a description of
the machine they ran on."""

from ._machine import machine_description
from ._runner import (
    HEADLINE,
    LOWER_IS_BETTER,
    PAPERS,
    SUITES,
    BenchInterrupted,
    check_report_dir,
    compare,
    run_suite,
)

__all__ = ["HEADLINE", "SUITES", "BenchInterrupted", "check_report_dir", "compare",
           "machine_description", "run_suite",
           "LOWER_IS_BETTER", "PAPERS"]
