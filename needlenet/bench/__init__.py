"""Benchmarks: ``needlenet bench SUITE``. Each suite measures on seeded data and reports
figures with a description of the machine they ran on."""

from ._machine import machine_description
from ._runner import SUITES, run_suite

__all__ = ["SUITES", "machine_description", "run_suite"]
