"""A program too large for the dry run: an error result, never a silent pass.

The command line and the server read at most :data:`MAX_PROGRAM_BYTES` of a program; a
larger one is not run and its result is one error saying so (docs/check.md#budgets), so a
release or a send is blocked until a programmer overrides it.
"""

from __future__ import annotations

from opendnc.nccheck.result import CheckResult, Control, Problem, Severity

__all__ = ["MAX_PROGRAM_BYTES", "not_checked"]

MAX_PROGRAM_BYTES = 16 * 1024 * 1024
"""Largest program the check reads (16 MiB: about a million blocks of CAM output)."""


def not_checked(name: str, size: int, control: Control) -> CheckResult:
    """The result of a program of ``size`` bytes (more than :data:`MAX_PROGRAM_BYTES`)."""
    problem = Problem(
        1,
        Severity.ERROR,
        f"not checked: {size / 1e6:.1f} MB is more than the check reads "
        f"({MAX_PROGRAM_BYTES // (1024 * 1024)} MiB)",
    )
    return CheckResult(control=control, name=name, problems=(problem,))
