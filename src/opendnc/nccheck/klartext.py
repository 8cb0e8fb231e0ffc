"""The Heidenhain conversational (Klartext) dry run."""

from __future__ import annotations

from opendnc.nccheck.api import Budget, Library
from opendnc.nccheck.limits import MachineLimits
from opendnc.nccheck.result import CheckResult, Control, Problem, Severity

__all__ = ["run_klartext"]


def run_klartext(
    text: str,
    *,
    name: str,
    machine: MachineLimits | None,
    library: Library | None,
    budget: Budget,
) -> CheckResult:
    """Dry-run a Klartext program (in progress: reports that it is not checked yet)."""
    problem = Problem(1, Severity.WARNING, "the Klartext dry run is not implemented yet")
    return CheckResult(control=Control.HEIDENHAIN, name=name, problems=(problem,))
