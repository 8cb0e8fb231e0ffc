"""Options of `opendnc lsv2 --serial ...`: LSV2 over an RS-232 line (docs/lsv2-serial.md)."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, get_args

import typer

from opendnc.cli.common import err_console
from opendnc.errors import InputError
from opendnc.transport.line import Handshake

if TYPE_CHECKING:  # the LSV2 stack loads with a command that connects, not for --help
    from opendnc.lsv2.serial_stream import SerialLine

FLOW_CONTROLS = get_args(Handshake)

__all__ = [
    "BaudOpt",
    "BytesizeOpt",
    "FlowOpt",
    "ParityOpt",
    "SerialOpt",
    "StopbitsOpt",
    "TelegramSizeOpt",
    "resolve_baud",
    "serial_line",
]

SerialOpt = typer.Option(
    None,
    "--serial",
    envvar="OPENDNC_LSV2_SERIAL",
    help="Reach the control over RS-232: a device (/dev/ttyUSB0, COM3), socket://HOST:PORT "
    "or rfc2217://HOST:PORT. --host/--port are then ignored.",
)
BaudOpt = typer.Option(
    "57600", "--baud", help="Serial line rate, or 'auto' to find it with ENQ (57600 first)."
)
ParityOpt = typer.Option("E", "--parity", help="Serial parity: N, E or O.")
BytesizeOpt = typer.Option(8, "--bytesize", help="Serial data bits: 7 or 8.")
StopbitsOpt = typer.Option(1.0, "--stopbits", help="Serial stop bits: 1, 1.5 or 2.")
FlowOpt = typer.Option("none", "--flow", help=f"Flow control: {', '.join(FLOW_CONTROLS)}.")
TelegramSizeOpt = typer.Option(
    256,
    "--telegram-size",
    help="Serial telegram size to ask for, 64-4096 bytes (uploads shrink below it on a bad "
    "line and grow back; 4096 is faster on a clean line).",
)


def serial_line(
    url: str | None,
    baud: str,
    parity: str,
    bytesize: int,
    stopbits: float,
    flow: str,
    telegram_size: int | None = None,
) -> SerialLine | None:
    """The :class:`SerialLine` of the ``--serial`` options (``None`` without ``--serial``)."""
    if not url:
        return None
    rate: int | None
    if baud.lower() == "auto":
        rate = None
    else:
        try:
            rate = int(baud)
        except ValueError:
            raise InputError(f"bad --baud {baud!r}: a number or 'auto'") from None
    from opendnc.lsv2.serial_stream import SerialLine

    return SerialLine(
        url,
        rate,
        parity=parity.upper(),
        bytesize=bytesize,
        stopbits=stopbits,
        flow=flow.lower(),
        telegram_size=telegram_size,
    )


def resolve_baud(line: SerialLine) -> SerialLine:
    """Probe the rate of a ``--baud auto`` line and say which one answered (on stderr)."""
    if line.baud is not None:
        return line
    from opendnc.lsv2.serial_stream import probe_baud

    rate = probe_baud(line)
    err_console.print(f"serial: the control answered at {rate} baud", highlight=False)
    return replace(line, baud=rate)
