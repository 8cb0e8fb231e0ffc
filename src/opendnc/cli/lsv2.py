"""`opendnc lsv2` commands: talk to a Heidenhain control over LSV2.

Global options (``--host``, ``--port``, ``--timeout``, ``--json``, ``--unsafe``) go before
the command; host and port also come from ``OPENDNC_LSV2_HOST`` / ``OPENDNC_LSV2_PORT``.
File and session commands live here, machine-data commands in :mod:`opendnc.cli.lsv2_machine`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.markup import escape

from opendnc.cli import lsv2_machine
from opendnc.cli.common import cli_errors, console, err_console, print_json
from opendnc.cli.lsv2_serial import (
    BaudOpt,
    BytesizeOpt,
    FlowOpt,
    ParityOpt,
    SerialOpt,
    StopbitsOpt,
    TelegramSizeOpt,
    serial_line,
)
from opendnc.cli.lsv2_session import JsonOpt, Settings, bar, connect, relabel, want_json
from opendnc.errors import ControlRefused, InputError

if TYPE_CHECKING:  # the LSV2 stack is imported by the commands that talk to a control
    from opendnc.lsv2 import Client, FileInfo
    from opendnc.lsv2.backup import Summary

app = typer.Typer(help="Heidenhain controls over LSV2 (TCP or RS-232).", no_args_is_help=True)


@app.callback()
def main(
    ctx: typer.Context,
    host: str = typer.Option(
        "127.0.0.1", "--host", "-H", envvar="OPENDNC_LSV2_HOST", help="Control address."
    ),
    port: int = typer.Option(19000, "--port", "-p", envvar="OPENDNC_LSV2_PORT", help="TCP port."),
    timeout: float = typer.Option(10.0, "--timeout", help="Seconds to wait for each answer."),
    json_out: bool = typer.Option(False, "--json", help="JSON output on read commands."),
    unsafe: bool = typer.Option(
        False, "--unsafe", help="Allow machine-changing actions (parameter, key, PLC writes)."
    ),
    serial: str | None = SerialOpt,
    baud: str = BaudOpt,
    parity: str = ParityOpt,
    bytesize: int = BytesizeOpt,
    stopbits: float = StopbitsOpt,
    flow: str = FlowOpt,
    telegram_size: int = TelegramSizeOpt,
) -> None:
    """Heidenhain controls over LSV2 (TCP, or RS-232 with --serial)."""
    with cli_errors():
        line = serial_line(serial, baud, parity, bytesize, stopbits, flow, telegram_size)
    ctx.obj = Settings(host, port, timeout, json_out, unsafe, line)


def as_typed(path: str, typed: str) -> str:
    r"""``path`` from the control in the separator style of what the user typed (``/`` or ``\``).

    The control answers with ``\``; someone who typed ``TNC:/nc_prog`` reads and pastes
    ``TNC:/nc_prog/POCKET.H`` back.
    """
    if "/" in typed and "\\" not in typed:
        return path.replace("\\", "/")
    return path


def _entry(info: FileInfo, typed: str = "\\") -> dict[str, object]:
    # one name per field everywhere: `modified`, as in the table and in FileInfo
    return {
        "name": info.name,
        "path": as_typed(info.path, typed),
        "size": info.size,
        "modified": info.modified.isoformat(),
        "is_dir": info.is_dir,
        "write_protected": info.write_protected,
        "selected": info.selected,
    }


def _show_entries(entries: list[FileInfo], title: str) -> None:
    from rich.table import Table

    table = Table(title=title, title_justify="left")
    table.add_column("name")
    table.add_column("size", justify="right")
    table.add_column("modified")
    for e in sorted(entries, key=lambda e: (not e.is_dir, e.name.lower())):
        name = f"[bold blue]{escape(e.name)}/[/]" if e.is_dir else escape(e.name)
        size = "" if e.is_dir else f"{e.size:,}"
        table.add_row(name, size, e.modified.strftime("%Y-%m-%d %H:%M:%S"))
    console.print(table)


@app.command("info")
def info(ctx: typer.Context, json_out: bool = JsonOpt) -> None:
    """Control model, family, software versions and protocol limits."""
    with cli_errors(), connect(ctx) as tnc:
        v, params = tnc.versions, tnc.parameters
        data: dict[str, object] = {
            "control": v.model,
            "family": tnc.family.name.lower(),
            "family_name": tnc.family.value,
            "nc_version": v.nc_software,
            "plc_version": v.plc,
            "splc_version": v.splc,
            "options": v.options,
            "control_id": v.control_id,
            "release_type": v.release_type,
            "lsv2_version": params.lsv2_version,
            "lsv2_flags": params.lsv2_flags,
            "max_block_length": params.max_block_length,
            "buffer_size": tnc.buffer_size,
            "secure_file_send": tnc.secure_file_send,
            "system_info": tnc.system_info(),
        }
        if want_json(ctx, json_out):
            print_json(data)
            return
        from rich.table import Table

        where = tnc.serial.describe() if tnc.serial else f"{tnc.host}:{tnc.port}"
        table = Table(show_header=False, title=f"{v.model} at {where}")
        for key, value in data.items():
            table.add_row(key.replace("_", " "), _readable(value))
        console.print(table)


def _readable(value: object) -> str:
    # a nested result (system info) as "name=value" pairs, not as its Python repr
    if value is None:
        return "n/a"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return "  ".join(
            f"{f.name}={_readable(getattr(value, f.name))}" for f in dataclasses.fields(value)
        )
    return str(value)


@app.command("ls")
def ls(
    ctx: typer.Context,
    path: str = typer.Argument("TNC:/", help="Remote folder (/ or \\ separators)."),
    json_out: bool = JsonOpt,
) -> None:
    """List a folder on the control."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"ls {path}"):
        entries = tnc.list_dir(path)
        if want_json(ctx, json_out):
            print_json([_entry(e, path) for e in entries])
        else:
            _show_entries(entries, path)


@app.command("stat")
def stat(ctx: typer.Context, path: str, json_out: bool = JsonOpt) -> None:
    """Size, time and attributes of a remote file or folder."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"stat {path}"):
        found = tnc.file_info(path)
        if found is None:
            raise ControlRefused(32, "file not found", context=f"stat {path}")
        if want_json(ctx, json_out):
            print_json(_entry(found, path))
        else:
            for key, value in _entry(found, path).items():
                console.print(f"{key:16} {value}", highlight=False)


def _split_targets(paths: list[str], what: str) -> tuple[list[str], str]:
    if len(paths) < 2:
        raise InputError(f"{what} needs a source and a destination")
    return paths[:-1], paths[-1]


BinaryOpt = typer.Option(
    None, "--binary/--ascii", help="Transfer mode (default: by file type, programs in ASCII)."
)


@app.command("get")
def get(
    ctx: typer.Context,
    paths: list[str] = typer.Argument(..., help="REMOTE... LOCAL (a folder for many files)."),
    binary: bool | None = BinaryOpt,
) -> None:
    """Download files from the control."""
    with cli_errors(), connect(ctx) as tnc:
        sources, local = _split_targets(paths, "get")
        target = Path(local)
        if len(sources) > 1 and not target.is_dir():
            raise InputError(f"{local} must be an existing folder when getting several files")
        sizes = []
        for remote in sources:
            with relabel(f"get {remote}"):
                found = tnc.file_info(remote)
                if found is None or found.is_dir:
                    raise ControlRefused(32, "file not found", context=f"get {remote}")
            sizes.append(found.size)
        _transfer_many(tnc, sources, sizes, local, binary, download=True)


@app.command("put")
def put(
    ctx: typer.Context,
    paths: list[str] = typer.Argument(..., help="LOCAL... REMOTE (a folder for many files)."),
    binary: bool | None = BinaryOpt,
) -> None:
    """Upload files to the control (an existing file is replaced)."""
    with cli_errors(), connect(ctx) as tnc:
        sources, remote = _split_targets(paths, "put")
        sizes = []
        for local in sources:
            try:
                sizes.append(Path(local).stat().st_size)
            except OSError as exc:
                raise InputError(f"put {local}: {exc.strerror or exc}") from exc
        if len(sources) > 1 and not remote.endswith(("/", "\\", ":")):
            remote += "/"
        _transfer_many(tnc, sources, sizes, remote, binary, download=False)


def _transfer_many(
    tnc: Client,
    sources: list[str],
    sizes: list[int],
    target: str,
    binary: bool | None,
    *,
    download: bool,
) -> None:
    """Move several files with one progress bar across all of them."""
    verb = "get" if download else "put"
    total = sum(sizes)
    with bar(quiet=False) as progress:
        task = progress.add_task(verb, total=total)
        base = 0
        for source, size in zip(sources, sizes, strict=True):
            progress.update(task, description=f"{verb} {source}")

            def report(done: int, _total: int | None, base: int = base) -> None:
                progress.update(task, completed=base + done)

            with relabel(f"{verb} {source}"):
                if download:
                    moved = tnc.download(source, target, binary=binary, progress=report)
                else:
                    moved = tnc.upload(source, target, binary=binary, progress=report)
            base += size
            progress.update(task, completed=base)
            landed = _landed(source, target, download=download)
            console.print(f"{verb} {source} -> {landed} ({moved:,} bytes)", highlight=False)
    changes = tnc.telegram_changes
    if changes:
        # the line was bad enough to change the upload telegram size (docs/lsv2-serial.md)
        steps = " -> ".join(str(n) for n in [changes[0][0], *(new for _, new in changes)])
        err_console.print(f"serial: telegram size {steps} bytes", highlight=False)
    if tnc.serial_restarts:
        err_console.print(
            f"serial: {tnc.serial_restarts} transfer(s) started again after a link failure",
            highlight=False,
        )


def _landed(source: str, target: str, *, download: bool) -> str:
    """Where ``source`` ends up when copied to ``target`` (a file name or a folder)."""
    if download:
        local = Path(target)
        if local.is_dir():
            name = source.replace("\\", "/").rsplit("/", 1)[-1].rsplit(":", 1)[-1]
            return str(local / name)
        return target
    if target.endswith(("/", "\\", ":")):
        return target + Path(source).name
    return target


@app.command("mkdir")
def mkdir(ctx: typer.Context, path: str) -> None:
    """Create a folder (and its parents) on the control."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"mkdir {path}"):
        created = tnc.make_dir(path, parents=True)
        console.print(f"{path}: {'created' if created else 'exists already'}", highlight=False)


@app.command("rm")
def rm(ctx: typer.Context, path: str) -> None:
    """Delete a file on the control."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"rm {path}"):
        if tnc.file_info(path) is None:
            raise ControlRefused(32, "file not found", context=f"rm {path}")
        tnc.delete_file(path)
        console.print(f"deleted {path}", highlight=False)


@app.command("rmdir")
def rmdir(ctx: typer.Context, path: str) -> None:
    """Delete an empty folder on the control."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"rmdir {path}"):
        tnc.remove_dir(path)
        console.print(f"removed {path}", highlight=False)


@app.command("mv")
def mv(ctx: typer.Context, src: str, dst: str) -> None:
    """Move or rename a file on the control."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"mv {src}"):
        tnc.move_file(src, dst)
        console.print(f"{src} -> {dst}", highlight=False)


@app.command("cp")
def cp(ctx: typer.Context, src: str, dst: str) -> None:
    """Copy a file on the control."""
    with cli_errors(), connect(ctx) as tnc, relabel(f"cp {src}"):
        tnc.copy_file(src, dst)
        console.print(f"{src} -> {dst}", highlight=False)


def _report(summary: Summary, as_json: bool, verb: str, typed: str) -> None:
    if as_json:
        print_json(
            {
                "copied": [as_typed(p, typed) for p in summary.copied],
                "skipped": [as_typed(p, typed) for p in summary.skipped],
                "failed": [
                    {"path": as_typed(f.path, typed), "reason": f.reason} for f in summary.failed
                ],
                "bytes": summary.bytes,
                "folders_created": summary.folders_created,
            }
        )
    else:
        for failure in summary.failed:
            console.print(
                f"[red]failed[/] {as_typed(failure.path, typed)}: {failure.reason}",
                highlight=False,
            )
        console.print(
            f"{verb}: {len(summary.copied)} copied, {len(summary.skipped)} up to date, "
            f"{len(summary.failed)} failed, {summary.bytes:,} bytes",
            highlight=False,
        )
    if summary.failed:
        raise typer.Exit(1)


@app.command("backup")
def backup_cmd(
    ctx: typer.Context,
    remote_dir: str = typer.Argument(..., help="Remote folder or drive, e.g. TNC:/"),
    local_dir: Path = typer.Argument(..., help="Local folder (created if missing)."),
    json_out: bool = JsonOpt,
) -> None:
    """Copy a remote folder tree to a local folder; a re-run skips unchanged files."""
    as_json = want_json(ctx, json_out)
    with cli_errors(), connect(ctx) as tnc, relabel(f"backup {remote_dir}"):
        with bar(quiet=as_json) as progress:
            task = progress.add_task("backup", total=None)

            def report(done: int, total: int, name: str) -> None:
                progress.update(task, completed=done, total=total, description=name)

            from opendnc.lsv2.backup import backup

            summary = backup(tnc, remote_dir, local_dir, progress=report)
        _report(summary, as_json, "backup", remote_dir)


@app.command("sync")
def sync_cmd(
    ctx: typer.Context,
    local_dir: Path = typer.Argument(..., help="Local folder to push."),
    remote_dir: str = typer.Argument(..., help="Remote folder (created if missing)."),
    json_out: bool = JsonOpt,
) -> None:
    """Push new and changed files of a local folder to the control."""
    as_json = want_json(ctx, json_out)
    with cli_errors(), connect(ctx) as tnc, relabel(f"sync {remote_dir}"):
        with bar(quiet=as_json) as progress:
            task = progress.add_task("sync", total=None)

            def report(done: int, total: int, name: str) -> None:
                progress.update(task, completed=done, total=total, description=name)

            from opendnc.lsv2.backup import sync

            summary = sync(tnc, local_dir, remote_dir, progress=report)
        _report(summary, as_json, "sync", remote_dir)


# Machine-data commands come last so that `--help` lists them after the file commands.
for _name, _func in lsv2_machine.COMMANDS.items():
    app.command(_name)(_func)
for _name, _group in lsv2_machine.GROUPS.items():
    app.add_typer(_group, name=_name)
