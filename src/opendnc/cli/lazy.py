"""Command groups whose subcommands are imported on first use, and the root group's rules.

A :class:`Lazy` entry names a subcommand by ``"module:attribute"`` plus the one line its
parent's ``--help`` shows, so listing commands imports nothing. The attribute is a
``typer.Typer`` (a sub-group) or a plain command function. :func:`lazy_typer` makes a
``typer.Typer`` from such a table; see :mod:`opendnc.cli.main` for how to add one.

The root group (:class:`RootGroup`) adds what every command shares:

- global options (``--host --port --timeout --json --unsafe``, short ``-H -p``) are accepted
  before or after the subcommand: they are moved to the deepest command on the command line
  that declares them (the leaf, else its group), see :func:`place_global_options`;
- usage errors are one line on stderr, exit status 2 (like every other failure, which is one
  line and status 1);
- the command line as typed is kept, so a refusal can print the exact line that would run it
  (:func:`unsafe_command_line`).
"""

from __future__ import annotations

import re
import shlex
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from difflib import get_close_matches
from importlib import import_module
from typing import Any, ClassVar, cast

import typer
from typer.core import TyperGroup

from opendnc.cli import clicklib as click

__all__ = [
    "GLOBAL_OPTIONS",
    "Lazy",
    "LazyGroup",
    "RootGroup",
    "lazy_typer",
    "place_global_options",
    "unsafe_command_line",
]

#: Options every group accepts before or after its subcommand (where a command declares them).
GLOBAL_OPTIONS = frozenset({"--host", "-H", "--port", "-p", "--timeout", "--json", "--unsafe"})
VALUE_OPTIONS = frozenset({"--host", "-H", "--port", "-p", "--timeout"})
ARGV_KEY = "opendnc.argv"


@dataclass(frozen=True, slots=True)
class Lazy:
    """A subcommand imported when it is used: ``target`` is ``"package.module:attribute"``."""

    target: str
    help: str

    def load(self, name: str) -> click.Command:
        """Import the target and turn it into a click command called ``name``."""
        module_name, _, attribute = self.target.partition(":")
        obj = getattr(import_module(module_name), attribute)
        if isinstance(obj, typer.Typer):
            command: click.Command = typer.main.get_group(obj)
        else:
            single = typer.Typer(add_completion=False)
            single.command(name, help=None)(obj)
            command = typer.main.get_command(single)
        command.name = name
        _plain_help(command)
        return command


def _plain_help(command: click.Command, inherited: tuple[str, ...] = ()) -> None:
    # click's plain help everywhere: rich's renderer costs more start-up than the CLI may add
    if hasattr(command, "rich_markup_mode"):
        command.rich_markup_mode = None
    own = {opt for p in command.params if _is_option(p) for opt in p.opts}
    subs = getattr(command, "commands", {})
    if not subs:
        # a command's --help names the group's global options it also accepts after its name
        extra = [opt for opt in inherited if opt not in own]
        if extra:
            note = "Also accepted here (options of the group): " + " ".join(extra) + "."
            command.epilog = f"{command.epilog}\n\n{note}" if command.epilog else note
        return
    mine = tuple(o for o in sorted(own) if o in GLOBAL_OPTIONS and o.startswith("--"))
    for sub in subs.values():
        _plain_help(sub, tuple(dict.fromkeys((*inherited, *mine))))


class LazyGroup(TyperGroup):
    """A typer group that also holds :class:`Lazy` entries (set by :func:`lazy_typer`)."""

    lazy: ClassVar[Mapping[str, Lazy]] = {}

    def list_commands(self, ctx: click.Context) -> list[str]:
        names = list(self.lazy)
        return names + [name for name in self.commands if name not in self.lazy]

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.commands and cmd_name in self.lazy:
            self.commands[cmd_name] = self.lazy[cmd_name].load(cmd_name)
        return self.commands.get(cmd_name)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        # the help of a command not imported yet comes from its Lazy entry, not from importing it
        rows = []
        for name in self.list_commands(ctx):
            loaded = self.commands.get(name)
            if loaded is None:
                rows.append((name, self.lazy[name].help))
            elif not loaded.hidden:
                rows.append((name, loaded.get_short_help_str(limit=formatter.width - 12)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def resolve_command(
        self, ctx: click.Context, args: list[str]
    ) -> tuple[str | None, click.Command | None, list[str]]:
        try:
            return self._click_resolve_command(ctx, args)
        except click.UsageError as exc:
            matches = get_close_matches(args[0], self.list_commands(ctx)) if args else []
            if matches:
                exc.message = exc.message.rstrip(".") + f"; did you mean {matches[0]!r}?"
            raise


def lazy_typer(help: str, entries: Mapping[str, Lazy], *, root: bool = False) -> typer.Typer:
    """A ``typer.Typer`` group whose ``entries`` load on first use.

    More commands can still be added eagerly with ``@app.command()``. Help is formatted by
    click's plain formatter (``rich_markup_mode=None``): rich's help renderer alone costs
    more start-up time than the whole CLI may add.
    """
    base = RootGroup if root else LazyGroup
    group = cast(type[LazyGroup], type(base.__name__, (base,), {"lazy": dict(entries)}))
    app = typer.Typer(
        cls=group,
        help=help,
        no_args_is_help=True,
        add_completion=root,  # `opendnc --install-completion`, as before
        rich_markup_mode=None,
        pretty_exceptions_enable=False,
    )

    if root:

        @app.callback()
        def _root_group(
            version: bool = typer.Option(
                False,
                "--version",
                help="Print the opendnc version and exit.",
                is_eager=True,
                callback=_print_version,
            ),
        ) -> None:
            pass

        _root_group.__doc__ = help
        return app

    @app.callback()
    def _group() -> None:
        pass

    _group.__doc__ = help
    return app


def _print_version(value: bool) -> None:
    if value:
        from opendnc import __version__

        typer.echo(f"opendnc {__version__}")
        raise typer.Exit()


# --------------------------------------------------------------------------- global options
def _is_group(command: click.Command) -> bool:
    return hasattr(command, "get_command") and hasattr(command, "list_commands")


def _is_option(param: click.Parameter) -> bool:
    return getattr(param, "param_type_name", "") == "option"


def _declared(command: click.Command, token: str) -> click.Parameter | None:
    for param in command.params:
        if _is_option(param) and token in (*param.opts, *param.secondary_opts):
            return param
    return None


def _takes_value(param: click.Parameter | None, token: str) -> bool:
    if param is None or "=" in token:
        return False
    if getattr(param, "is_flag", False) or getattr(param, "count", False):
        return False
    return param.nargs != 0


def place_global_options(root: click.Command, ctx: click.Context, args: Sequence[str]) -> list[str]:
    """Move each global option to the deepest command in ``args`` that declares it.

    ``opendnc lsv2 info --host X`` becomes ``opendnc lsv2 --host X info`` (``--host`` belongs
    to the ``lsv2`` group) and ``opendnc haas --host X q Q500`` becomes ``haas q Q500 --host X``
    (``q`` declares its own). An option nobody on the line declares stays where it is, so
    click reports it. Everything after ``--`` is left alone.
    """
    levels: list[tuple[click.Command, list[str]]] = [(root, [])]
    names: list[str] = []
    moved: list[list[str]] = []
    tokens = list(args)
    i = 0
    while i < len(tokens):
        token = tokens[i]
        command, own = levels[-1]
        if token == "--":
            own.extend(tokens[i:])
            break
        name = token.split("=", 1)[0]
        if token.startswith("-") and len(token) > 1:
            if name in GLOBAL_OPTIONS:
                takes_value = name in VALUE_OPTIONS and "=" not in token
                width = 2 if takes_value and i + 1 < len(tokens) else 1
                moved.append(tokens[i : i + width])
            else:
                param = _declared(command, name)
                width = 2 if _takes_value(param, token) and i + 1 < len(tokens) else 1
                own.extend(tokens[i : i + width])
            i += width
            continue
        sub = command.get_command(ctx, token) if _is_group(command) else None  # type: ignore[attr-defined]
        if sub is None:
            own.append(token)
        else:
            names.append(token)
            levels.append((sub, []))
        i += 1
    for option in moved:
        for command, own in reversed(levels):
            if _declared(command, option[0].split("=", 1)[0]) is not None:
                own[:0] = option  # options first: a leaf's own positional args stay in order
                break
        else:
            levels[-1][1].extend(option)
    out: list[str] = []
    for index, (_command, own) in enumerate(levels):
        out.extend(own)
        if index < len(names):
            out.append(names[index])
    return out


def unsafe_command_line() -> str:
    """The command line being run, with ``--unsafe`` added (for a refusal message)."""
    ctx = click.get_current_context(silent=True)
    if ctx is None:
        return "--unsafe"
    root = ctx.find_root()
    args = list(root.meta.get(ARGV_KEY, []))
    cut = args.index("--") if "--" in args else len(args)
    args[cut:cut] = ["--unsafe"]
    prog = root.info_name or "opendnc"
    return " ".join([prog, shlex.join(args)])


class RootGroup(LazyGroup):
    """The ``opendnc`` group: global option placement and one-line usage errors."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        ctx.meta[ARGV_KEY] = list(args)
        return super().parse_args(ctx, place_global_options(self, ctx, args))

    def main(
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        windows_expand_args: bool = True,
        **extra: Any,
    ) -> Any:
        try:
            result = super().main(
                args, prog_name, complete_var, False, windows_expand_args, **extra
            )
        except click.UsageError as exc:
            code = _report_usage(exc)
        except click.ClickException as exc:
            _error_line(exc.format_message())
            code = exc.exit_code
        except typer.Abort:
            _error_line("aborted")
            code = 1
        else:
            if not standalone_mode:
                return result
            code = result if isinstance(result, int) else 0
        if not standalone_mode:
            raise SystemExit(code)
        sys.exit(code)


def _error_line(message: str) -> None:
    text = plain_message(message)
    sys.stderr.write(f"error: {text}\n")
    sys.stderr.flush()


# a capitalised English word where a sentence starts: the start, after ". ", ": " or "("
_SENTENCE_START = re.compile(r"(^|\. |: |\()([A-Z][a-z]+)\b")


def plain_message(message: str) -> str:
    """Click's own messages in our style: one line, lower case, no full stop.

    ``No such command 'inf'. Did you mean 'info'?`` becomes
    ``no such command 'inf'; did you mean 'info'?``; names in quotes and upper-case words
    (``TNC``, ``'X'``) stay as they are.
    """
    text = " ".join(message.split()).replace(": Value error, ", ": ")
    text = _SENTENCE_START.sub(lambda m: m.group(1) + m.group(2).lower(), text)
    text = text.replace(". ", "; ")
    return text[:-1] if text.endswith(".") else text


def _report_usage(exc: click.UsageError) -> int:
    if isinstance(exc, click.NoArgsIsHelpError):
        exc.show()  # a group called without a command prints its help
        return exc.exit_code
    where = exc.ctx.command_path if exc.ctx is not None else "opendnc"
    _error_line(f"{plain_message(exc.format_message())} (see '{where} --help')")
    return exc.exit_code
