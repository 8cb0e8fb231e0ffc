"""LSV2 client for asyncio: :class:`AsyncClient`.

Usage::

    from opendnc.lsv2 import AsyncClient, KeyCode

    async with AsyncClient("192.168.56.101") as tnc:
        print(tnc.versions.model, tnc.family)
        for entry in await tnc.list_dir("TNC:/nc_prog"):
            print(entry.name, entry.size)
        await tnc.download("TNC:/nc_prog/PART.H", "PART.H")
        await tnc.upload("NEW.H", "TNC:/nc_prog/", progress=lambda done, total: None)
        print(await tnc.program_state(), await tnc.read_plc("W4", 3))
        print((await tnc.read_table()).to_json())          # the family's tool table
        await tnc.screen_dump("screen.png")

    # machine-changing actions (keys, machine parameters, tables, PLC files) need:
    async with AsyncClient("192.168.56.101", safe_mode=False) as tnc:
        await tnc.send_key(KeyCode.MODE_MANUAL)

Every operation logs in as needed, has a timeout, raises :class:`~opendnc.errors.ControlRefused`
(code + readable text) when the control says no, :class:`~opendnc.errors.TransportError` /
:class:`~opendnc.errors.PeerClosed` when the link fails, and
:class:`~opendnc.errors.SafetyLockError` for machine-changing actions unless the client was
created with ``safe_mode=False``.
"""

from __future__ import annotations

import contextlib
import os
from datetime import UTC, datetime
from types import TracebackType
from typing import Any

from opendnc.errors import DncError, LocalProtocolError, TransferError
from opendnc.lsv2 import ops
from opendnc.lsv2.connection import BytesHook, TraceHook
from opendnc.lsv2.constants import (
    DEFAULT_PORT,
    ExecutionMode,
    Family,
    Login,
    MemoryType,
    ProgramState,
)
from opendnc.lsv2.drive import AsyncDriver
from opendnc.lsv2.localfiles import AtomicFile, image_bytes, is_binary_name, read_local
from opendnc.lsv2.ops.base import Op, T
from opendnc.lsv2.ops.extras import ScopeRecording
from opendnc.lsv2.ops.files import FileInfo, Progress, text_size
from opendnc.lsv2.ops.machine import Uptimes
from opendnc.lsv2.ops.session import SystemInfo
from opendnc.lsv2.payloads import (
    DirectoryInfo,
    ScopeChannel,
    ScopeSignal,
    SystemParameters,
    Versions,
    to_wire_ascii,
)
from opendnc.lsv2.plc import PlcOperand, PlcValue
from opendnc.lsv2.runinfo import (
    AxesConfig,
    AxesNames,
    AxesPositions,
    NcError,
    Overrides,
    RunInfoValue,
    SelectedProgram,
    ToolInfo,
)
from opendnc.lsv2.serial_link import SerialLinkError
from opendnc.lsv2.serial_stream import SerialLine
from opendnc.lsv2.tables import Table

__all__ = ["AsyncClient"]

PathLike = str | os.PathLike[str]


class AsyncClient:
    """An LSV2 session with one control (see the module docstring).

    Safety: anything that can change machine behaviour (machine-parameter writes, key presses
    and keyboard lock, explicit PLCDEBUG/DNC logins, writes into PLC files or tables) raises
    :class:`~opendnc.errors.SafetyLockError` unless the client was created with
    ``safe_mode=False``; reads that need those logins still take them internally.
    """

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        timeout: float = 10.0,
        safe_mode: bool = True,
        max_buffer: int = 4096,
        secure_send: bool = True,
        passwords: dict[str, str] | None = None,
        trace: TraceHook | None = None,
        trace_bytes: BytesHook | None = None,
        serial: SerialLine | None = None,
    ) -> None:
        """Prepare a session; nothing is sent before :meth:`connect` (or ``async with``).

        ``max_buffer`` caps the telegram size negotiated with the control (256 = no
        negotiation, the compatibility setting); ``passwords`` maps login names (e.g.
        ``"FILEPLC"``, ``"PLCDEBUG"``) to the passwords used when an operation needs them;
        ``trace`` is called with ``("send"|"recv", message)`` for every telegram and
        ``trace_bytes`` with ``("send"|"recv", raw bytes)`` for every write and read.
        """
        self.host, self.port = host, port
        self.timeout = timeout
        """Seconds to wait for each answer (may be changed at any time)."""
        self.safe_mode = safe_mode
        self.max_buffer = max_buffer
        self.secure_send = secure_send
        self.passwords = dict(passwords or {})
        self.trace = trace
        self.trace_bytes = trace_bytes
        self.serial = serial
        """RS-232 line settings when the control is reached over serial LSV2 (else TCP)."""
        self._driver: AsyncDriver | None = None
        self.serial_checks = 0
        """Text uploads verified end to end over serial (docs/lsv2-serial.md)."""
        self.serial_readbacks = 0
        """Of those, how many needed a read-back (the reported size was not the expected)."""
        self.serial_attempts = 3
        """Tries of one file transfer over serial when the link gives a telegram up."""
        self.serial_restarts = 0
        """Transfers started again over a fresh serial link."""

    @classmethod
    def over_serial(cls, line: SerialLine | str, **options: Any) -> AsyncClient:
        """A client for a control on an RS-232 line (a device, ``socket://`` or ``rfc2217://``).

        ``line`` is a :class:`~opendnc.lsv2.serial_stream.SerialLine` or just the port (then
        57600 baud 8E1); ``options`` are those of the constructor. The telegram buffer starts
        at 256 bytes and is raised only if the control accepts it (``max_buffer`` caps it);
        ``trace_bytes`` sees the serial line's own bytes (handshake characters included).
        """
        settings = SerialLine(line) if isinstance(line, str) else line
        return cls(settings.url, 0, serial=settings, **options)

    # -- session ---------------------------------------------------------------------------

    async def connect(self) -> None:
        """Open the TCP connection and run the start-up sequence."""
        if self._driver is not None:
            return
        driver = await AsyncDriver.open(
            self.host,
            self.port,
            timeout=self.timeout,
            safe_mode=self.safe_mode,
            trace=self.trace,
            trace_bytes=self.trace_bytes,
            serial=self.serial,
        )
        driver.state.passwords.update(self.passwords)
        self._driver = driver
        try:
            limit = self.max_buffer
            if self.serial is not None and self.serial.telegram_size is not None:
                limit = min(limit, self.serial.telegram_size)
            await driver.run(
                ops.connect(driver.state, max_buffer=limit, secure_send=self.secure_send)
            )
        except BaseException:
            self._driver = None
            await driver.close()
            raise

    async def close(self) -> None:
        """Log out (best effort) and close the connection."""
        driver, self._driver = self._driver, None
        if driver is None:
            return
        try:
            if not driver.broken:
                # Best effort: the control may already be gone; closing must still succeed.
                with contextlib.suppress(DncError):
                    await driver.run(ops.logout(driver.state))
        finally:
            await driver.close()

    async def __aenter__(self) -> AsyncClient:
        await self.connect()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    async def _run(self, op: Op[T]) -> T:
        if self._driver is None:
            op.close()
            raise LocalProtocolError("not connected: call connect() or use a with block")
        self._driver.timeout = self.timeout
        return await self._driver.run(op)

    @property
    def _state(self) -> ops.SessionState:
        if self._driver is None:
            raise LocalProtocolError("not connected: call connect() or use a with block")
        return self._driver.state

    @property
    def connected(self) -> bool:
        """True between :meth:`connect` and :meth:`close`."""
        return self._driver is not None

    @property
    def versions(self) -> Versions:
        """Version strings read during connect."""
        versions = self._state.versions
        assert versions is not None
        return versions

    @property
    def family(self) -> Family:
        """Control family detected from the model string."""
        return self._state.family

    @property
    def parameters(self) -> SystemParameters:
        """System parameters read during connect."""
        return self._state.require_params()

    @property
    def buffer_size(self) -> int:
        """Negotiated telegram size in bytes."""
        return self._state.buffer_size

    @property
    def telegram_changes(self) -> list[tuple[int, int]]:
        """Upload telegram sizes changed over serial, as ``(old, new)`` (docs/lsv2-serial.md)."""
        sizer = self._state.sizer
        return list(sizer.changes) if sizer is not None else []

    @property
    def secure_file_send(self) -> bool:
        """True if the control acknowledges the end of uploads (``C_CC`` 19 accepted)."""
        return self._state.secure_send

    @property
    def logins(self) -> frozenset[str]:
        """Logins held in this session."""
        return frozenset(self._state.logins)

    async def login(self, name: Login | str, password: str | None = None) -> None:
        """Log in explicitly (operations log in by themselves when needed).

        PLCDEBUG and DNC need ``safe_mode=False``; in safe mode they raise
        :class:`~opendnc.errors.SafetyLockError`.
        """
        await self._run(ops.login(self._state, name, password))

    async def logout(self, name: Login | str | None = None) -> None:
        """Drop one login, or all."""
        await self._run(ops.logout(self._state, name))

    async def read_versions(self) -> Versions:
        """Read the version strings again."""
        return await self._run(ops.read_versions(self._state))

    async def read_parameters(self) -> SystemParameters:
        """Read the system parameters again."""
        return await self._run(ops.read_parameters(self._state))

    async def system_info(self) -> SystemInfo:
        """``R_CI``: turbo mode, DNC allowed, axes sampling rate (``None`` if unsupported)."""
        return await self._run(ops.system_info_all(self._state))

    # -- files -----------------------------------------------------------------------------

    async def drives(self) -> list[FileInfo]:
        """Drives of the control (``TNC:``, ``PLC:`` ...)."""
        return await self._run(ops.drives(self._state))

    async def dir_info(self, path: str | None = None) -> DirectoryInfo:
        """Free space and path of ``path`` (changes into it) or the current directory."""
        return await self._run(ops.dir_info(self._state, path))

    async def change_dir(self, path: str) -> None:
        """Change the current directory on the control."""
        await self._run(ops.change_dir(self._state, path))

    async def list_dir(self, path: str | None = None, *, multi: bool = True) -> list[FileInfo]:
        """Files and directories in ``path`` (or the current directory)."""
        return await self._run(ops.list_dir(self._state, path, multi=multi))

    async def walk(self, path: str = "TNC:\\", *, multi: bool = True) -> list[FileInfo]:
        """Every file and directory below ``path`` (for backups and searches)."""
        return await self._run(ops.walk(self._state, path, multi=multi))

    async def file_info(self, path: str) -> FileInfo | None:
        """Info on a file or directory; ``None`` if it does not exist."""
        return await self._run(ops.file_info(self._state, path))

    async def exists(self, path: str) -> bool:
        """True if ``path`` exists on the control."""
        return await self.file_info(path) is not None

    async def make_dir(self, path: str, *, parents: bool = True) -> bool:
        """Create a directory (and its parents); ``False`` if it existed."""
        return await self._run(ops.make_dir(self._state, path, parents=parents))

    async def remove_dir(self, path: str, *, missing_ok: bool = False) -> None:
        """Delete an empty directory."""
        await self._run(ops.remove_dir(self._state, path, missing_ok=missing_ok))

    async def delete_file(self, path: str, *, missing_ok: bool = False) -> None:
        """Delete a file."""
        await self._run(ops.delete_file(self._state, path, missing_ok=missing_ok))

    async def copy_file(self, source: str, target: str) -> None:
        """Copy a file on the control (target ending in ``/`` keeps the name)."""
        await self._run(ops.copy_file(self._state, source, target))

    async def move_file(self, source: str, target: str) -> None:
        """Move or rename a file on the control."""
        await self._run(ops.move_file(self._state, source, target))

    async def write_file(
        self,
        remote: str,
        data: bytes,
        *,
        binary: bool | None = None,
        overwrite: bool = True,
        progress: Progress | None = None,
    ) -> None:
        """Store ``data`` as ``remote``; ``binary=None`` picks the mode by file type."""
        mode = is_binary_name(remote) if binary is None else binary
        for attempt in range(1, self._attempts() + 1):
            try:
                await self._run(
                    ops.upload(
                        self._state,
                        remote,
                        data,
                        binary=mode,
                        overwrite=overwrite,
                        progress=progress,
                    )
                )
                break
            except SerialLinkError:
                if attempt >= self._attempts():
                    raise
                await self._reconnect()  # the control drops the partial file; start again
        if self.serial is not None:
            if mode:
                await self._check_serial_size(remote, len(data), upload=True)
            else:
                await self._check_serial_text(remote, data)

    def _attempts(self) -> int:
        # Over serial a transfer whose telegram the link gave up is started once more over a
        # fresh link (docs/lsv2-serial.md, "Telegram size"); over TCP a failure is final.
        return 1 if self.serial is None else self.serial_attempts

    async def _reconnect(self) -> None:
        driver, self._driver = self._driver, None
        if driver is not None:
            await driver.close()
        self.serial_restarts += 1
        await self.connect()

    async def _serial_fault(self, remote: str, what: str, *, upload: bool) -> TransferError:
        if upload:
            # no damaged program left on the control
            with contextlib.suppress(DncError):
                await self.delete_file(remote)
        return TransferError(f"{what}: the serial line let an error through; try again")

    async def _check_serial_size(self, remote: str, size: int, *, upload: bool) -> None:
        # Serial LSV2's XOR block check cannot see a lost NUL byte (docs/lsv2-serial.md, "What
        # the block check cannot see"): compare the sizes of binary files at both ends.
        info = await self.file_info(remote)
        if info is not None and info.size == size:
            return
        got = "no such file" if info is None else f"{info.size} bytes"
        what = f"{remote}: {got} on the control, {size} bytes here"
        raise await self._serial_fault(remote, what, upload=upload)

    async def _check_serial_text(self, remote: str, data: bytes) -> None:
        # Text has no size to compare as is: the control writes its own line end for every
        # NUL that ended a line on the wire. The size it reports is that of CR LF line ends
        # (docs/lsv2-serial.md, "Every text upload verified"); any other size is settled by
        # reading the file back, NUL line ends and all, and comparing it with what was sent.
        self.serial_checks += 1
        info = await self.file_info(remote)
        if info is not None and info.size == text_size(data):
            return
        if info is not None:
            self.serial_readbacks += 1
            sent = to_wire_ascii(data)
            back = await self.read_file(remote, binary=False, line_end=b"\0")
            if back == sent:
                return  # a control that stores other line ends: the text itself is exact
            what = f"{remote} reads back {len(back)} bytes on the control, {len(sent)} sent"
        else:
            what = f"{remote}: no such file on the control after the upload"
        raise await self._serial_fault(remote, what, upload=True)

    async def read_file(
        self, remote: str, *, binary: bool | None = None, line_end: bytes = b"\r\n"
    ) -> bytes:
        """Contents of ``remote``; ``binary=None`` picks the mode by file type."""
        mode = is_binary_name(remote) if binary is None else binary
        parts: list[bytes] = []
        await self._run(
            ops.download(self._state, remote, parts.append, binary=mode, line_end=line_end)
        )
        return b"".join(parts)

    async def upload(
        self,
        local: PathLike,
        remote: str,
        *,
        binary: bool | None = None,
        overwrite: bool = True,
        progress: Progress | None = None,
    ) -> int:
        """Send local file ``local`` to ``remote`` (a target ending in ``/`` keeps the name);
        returns the number of bytes sent."""
        target = remote
        if target.endswith(("/", "\\", ":")):
            target += os.path.basename(os.fspath(local))
        data = read_local(local)
        await self.write_file(target, data, binary=binary, overwrite=overwrite, progress=progress)
        return len(data)

    async def download(
        self,
        remote: str,
        local: PathLike,
        *,
        binary: bool | None = None,
        line_end: bytes = b"\r\n",
        progress: Progress | None = None,
    ) -> int:
        """Fetch ``remote`` into local file ``local`` (a folder keeps the name); written to a
        temporary file first and renamed on success. Returns the number of bytes stored."""
        target = os.fspath(local)
        if os.path.isdir(target):
            target = os.path.join(target, remote.replace("\\", "/").rsplit("/", 1)[-1])
        mode = is_binary_name(remote) if binary is None else binary
        for attempt in range(1, self._attempts() + 1):
            try:
                with AtomicFile(target) as out:
                    count = await self._run(
                        ops.download(
                            self._state,
                            remote,
                            out.write,
                            binary=mode,
                            line_end=line_end,
                            progress=progress,
                        )
                    )
                    if self.serial is not None and mode:
                        await self._check_serial_size(remote, count, upload=False)
                    return count
            except SerialLinkError:
                if attempt >= self._attempts():
                    raise
                await self._reconnect()  # no partial file was kept; fetch it again
        raise AssertionError("unreachable")

    # -- machine state ---------------------------------------------------------------------

    async def date_time(self) -> datetime:
        """The control's clock."""
        return await self._run(ops.date_time(self._state))

    async def run_info(self, selector: int) -> RunInfoValue:
        """Raw ``R_RI`` access by selector, decoded."""
        return await self._run(ops.run_info(self._state, selector))

    async def execution_mode(self) -> ExecutionMode:
        """Operating mode (manual, MDI, single block, automatic ...)."""
        return await self._run(ops.execution_mode(self._state))

    async def program_state(self) -> ProgramState:
        """Program state (started, stopped, idle ...)."""
        return await self._run(ops.program_state(self._state))

    async def selected_program(self) -> SelectedProgram:
        """Selected main program, executing (called) program and line: the program stack."""
        return await self._run(ops.selected_program(self._state))

    async def overrides(self) -> Overrides:
        """Feed, spindle and rapid overrides."""
        return await self._run(ops.overrides(self._state))

    async def axes_position(self) -> AxesPositions:
        """Current axis positions."""
        return await self._run(ops.axes_position(self._state))

    async def axes_names(self) -> AxesNames:
        """Physical axis names."""
        return await self._run(ops.axes_names(self._state))

    async def axes_config(self) -> AxesConfig:
        """Axis configuration."""
        return await self._run(ops.axes_config(self._state))

    async def current_tool(self) -> ToolInfo:
        """The tool in the spindle (iTNC 530)."""
        return await self._run(ops.current_tool(self._state))

    async def nc_errors(self) -> list[NcError]:
        """All pending NC error messages (iTNC 530)."""
        return await self._run(ops.nc_errors(self._state))

    async def uptimes(self) -> Uptimes:
        """NC, machine, run-time and spindle time counters."""
        return await self._run(ops.uptimes(self._state))

    # -- PLC, data paths, machine parameters -----------------------------------------------

    async def read_plc(self, operand: str | PlcOperand, count: int = 1) -> list[PlcValue]:
        """Read PLC operands by notation, e.g. ``read_plc("M100", 8)`` or ``"W4"``."""
        return await self._run(ops.read_plc(self._state, operand, count))

    async def read_plc_memory(
        self, memory: MemoryType, index: int, count: int = 1
    ) -> list[PlcValue]:
        """Read ``count`` elements of ``memory`` starting at element ``index``."""
        return await self._run(ops.read_plc_memory(self._state, memory, index, count))

    async def read_data_path(self, path: str) -> int | float | str | bool:
        """Read a value by data path, e.g. ``/TABLE/TOOL/T/1/L`` (iTNC 530)."""
        return await self._run(ops.read_data_path(self._state, path))

    async def read_machine_parameter(self, name: str) -> str:
        """A machine parameter's value as text."""
        return await self._run(ops.read_machine_parameter(self._state, name))

    async def write_machine_parameter(
        self, name: str, value: str, *, temporary: bool = False
    ) -> None:
        """Write a machine parameter (needs ``safe_mode=False``)."""
        await self._run(ops.write_machine_parameter(self._state, name, value, temporary=temporary))

    # -- keyboard, screen, logs, tables, scope ---------------------------------------------

    async def lock_keyboard(self, locked: bool = True) -> None:
        """Lock or unlock the control's keyboard (needs ``safe_mode=False``)."""
        await self._run(ops.lock_keyboard(self._state, locked))

    async def send_key(self, code: int, *, lock: bool = True) -> None:
        """Emulate a key press (needs ``safe_mode=False``); see ``KeyCode``/``OldKeyCode``."""
        await self._run(ops.emulate_key(self._state, code, lock=lock))

    async def screen_dump(self, local: PathLike | None = None) -> bytes:
        """Screenshot of the control as BMP; also saved to ``local`` (BMP, or PNG by suffix)."""
        bmp = await self._run(ops.screen_dump(self._state, stamp=datetime.now(UTC)))
        if local is not None:
            data = image_bytes(bmp, local)
            with AtomicFile(local) as out:
                out.write(data)
        return bmp

    async def operations_log(
        self, local: PathLike | None = None, *, since: datetime, name: str = "operation.log"
    ) -> bytes:
        """Have the control generate its operations log since ``since``; return (and save)."""
        data = await self._run(ops.operations_log(self._state, since=since, name=name))
        if local is not None:
            with AtomicFile(local) as out:
                out.write(data)
        return data

    async def read_table(self, remote: str | None = None) -> Table:
        """Parse a table file (default: the family's tool table)."""
        path = remote if remote is not None else ops.table_paths(self.family)[0]
        return await self._run(ops.read_table(self._state, path))

    async def write_table(self, remote: str, table: Table) -> None:
        """Write a table file (needs ``safe_mode=False``)."""
        await self._run(ops.write_table(self._state, remote, table))

    async def scope_channels(self) -> list[ScopeChannel]:
        """Remote-scope channels (iTNC 530)."""
        return await self._run(ops.scope_channels(self._state))

    async def scope_record(
        self, signals: list[ScopeSignal], *, interval: int = 21000, blocks: int = 1
    ) -> ScopeRecording:
        """Record ``blocks`` × 32 samples of ``signals`` every ``interval`` µs (iTNC 530)."""
        return await self._run(
            ops.scope_record(self._state, signals, interval=interval, blocks=blocks)
        )
