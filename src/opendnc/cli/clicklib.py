"""The click API the CLI plumbing uses, from typer's bundled copy or from click itself.

typer >= 0.2x bundles click (``typer._click``); older typer depends on click. Command modules
do not need this: they use ``typer`` only.
"""

from __future__ import annotations

try:
    from typer._click.core import Command, Context, Parameter
    from typer._click.exceptions import ClickException, UsageError
    from typer._click.formatting import HelpFormatter
    from typer._click.globals import get_current_context
except ImportError:  # pragma: no cover - typer on top of an installed click
    from click.core import Command, Context, Parameter  # type: ignore[no-redef,import-not-found,assignment,unused-ignore]
    from click.exceptions import ClickException, UsageError  # type: ignore[no-redef,import-not-found,assignment,unused-ignore]
    from click.formatting import HelpFormatter  # type: ignore[no-redef,import-not-found,assignment,unused-ignore]
    from click.globals import get_current_context  # type: ignore[no-redef,import-not-found,assignment,unused-ignore]

try:
    from typer._click.exceptions import NoArgsIsHelpError
except ImportError:  # pragma: no cover - click < 8.2 prints the help itself

    class NoArgsIsHelpError(UsageError):  # type: ignore[no-redef,import-not-found,assignment,unused-ignore]
        """Never raised by this click version."""


__all__ = [
    "ClickException",
    "Command",
    "Context",
    "HelpFormatter",
    "NoArgsIsHelpError",
    "Parameter",
    "UsageError",
    "get_current_context",
]
