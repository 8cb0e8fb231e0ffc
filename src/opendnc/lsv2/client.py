# Generated from aio.py by tools/unasync.py; edit aio.py, then regenerate.
"""Blocking LSV2 client: :class:`Client`.

Usage::

    from opendnc.lsv2 import Client, KeyCode

    with Client("192.168.56.101") as tnc:
        print(tnc.versions.model, tnc.family)
        for entry in tnc.list_dir("TNC:/nc_prog"):
            print(entry.name, entry.size)
        tnc.download("TNC:/nc_prog/PART.H", "PART.H")
        tnc.upload("NEW.H", "TNC:/nc_prog/", progress=lambda done, total: None)
        print(tnc.program_state(), tnc.read_plc("W4", 3))
        print((tnc.read_table()).to_json())          # the family's tool table
        tnc.screen_dump("screen.png")

    # machine-changing actions (keys, machine parameters, tables, PLC files) need:
    with Client("192.168.56.101", safe_mode=False) as tnc:
        tnc.send_key(KeyCode.MODE_MANUAL)

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
from opendnc.lsv2.drive import BlockingDriver
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

__all__ = ["Client"]

PathLike = str | os.PathLike[str]


class Client:
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
        """Prepare a session; nothing is sent before :meth:`connect` (or ``with``).

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
        self._driver: BlockingDriver | None = None
        self.serial_checks = 0
        """Text uploads verified end to end over serial (docs/lsv2-serial.md)."""
        self.serial_readbacks = 0
        """Of those, how many needed a read-back (the reported size was not the expected)."""
        self.serial_attempts = 3
        """Tries of one file transfer over serial when the link gives a telegram up."""
        self.serial_restarts = 0
        """Transfers started again over a fresh serial link."""

    @classmethod
    def over_serial(cls, line: SerialLine | str, **options: Any) -> Client:
        """A client for a control on an RS-232 line (a device, ``socket://`` or ``rfc2217://``).

        ``line`` is a :class:`~opendnc.lsv2.serial_stream.SerialLine` or just the port (then
        57600 baud 8E1); ``options`` are those of the constructor. The telegram buffer starts
        at 256 bytes and is raised only if the control accepts it (``max_buffer`` caps it);
        ``trace_bytes`` sees the serial line's own bytes (handshake characters included).
        """
        settings = SerialLine(line) if isinstance(line, str) else line
        return cls(settings.url, 0, serial=settings, **options)

    # -- session ---------------------------------------------------------------------------

    def connect(self) -> None:
        """Open the TCP connection and run the start-up sequence."""
        if self._driver is not None:
            return
        driver = BlockingDriver.open(
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
            driver.run(ops.connect(driver.state, max_buffer=limit, secure_send=self.secure_send))
        except BaseException:
            self._driver = None
            driver.close()
            raise

    def close(self) -> None:
        """Log out (best effort) and close the connection."""
        driver, self._driver = self._driver, None
        if driver is None:
            return
        try:
            if not driver.broken:
                # Best effort: the control may already be gone; closing must still succeed.
                with contextlib.suppress(DncError):
                    driver.run(ops.logout(driver.state))
        finally:
            driver.close()

    def __enter__(self) -> Client:
        self.connect()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def _run(self, op: Op[T]) -> T:
        if self._driver is None:
            op.close()
            raise LocalProtocolError("not connected: call connect() or use a with block")
        self._driver.timeout = self.timeout
        return self._driver.run(op)

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

    def login(self, name: Login | str, password: str | None = None) -> None:
        """Log in explicitly (operations log in by themselves when needed).

        PLCDEBUG and DNC need ``safe_mode=False``; in safe mode they raise
        :class:`~opendnc.errors.SafetyLockError`.
        """
        self._run(ops.login(self._state, name, password))

    def logout(self, name: Login | str | None = None) -> None:
        """Drop one login, or all."""
        self._run(ops.logout(self._state, name))

    def read_versions(self) -> Versions:
        """Read the version strings again."""
        return self._run(ops.read_versions(self._state))

    def read_parameters(self) -> SystemParameters:
        """Read the system parameters again."""
        return self._run(ops.read_parameters(self._state))

    def system_info(self) -> SystemInfo:
        """``R_CI``: turbo mode, DNC allowed, axes sampling rate (``None`` if unsupported)."""
        return self._run(ops.system_info_all(self._state))

    # -- files -----------------------------------------------------------------------------

    def drives(self) -> list[FileInfo]:
        """Drives of the control (``TNC:``, ``PLC:`` ...)."""
        return self._run(ops.drives(self._state))

    def dir_info(self, path: str | None = None) -> DirectoryInfo:
        """Free space and path of ``path`` (changes into it) or the current directory."""
        return self._run(ops.dir_info(self._state, path))

    def change_dir(self, path: str) -> None:
        """Change the current directory on the control."""
        self._run(ops.change_dir(self._state, path))

    def list_dir(self, path: str | None = None, *, multi: bool = True) -> list[FileInfo]:
        """Files and directories in ``path`` (or the current directory)."""
        return self._run(ops.list_dir(self._state, path, multi=multi))

    def walk(self, path: str = "TNC:\\", *, multi: bool = True) -> list[FileInfo]:
        """Every file and directory below ``path`` (for backups and searches)."""
        return self._run(ops.walk(self._state, path, multi=multi))

    def file_info(self, path: str) -> FileInfo | None:
        """Info on a file or directory; ``None`` if it does not exist."""
        return self._run(ops.file_info(self._state, path))

    def exists(self, path: str) -> bool:
        """True if ``path`` exists on the control."""
        return self.file_info(path) is not None

    def make_dir(self, path: str, *, parents: bool = True) -> bool:
        """Create a directory (and its parents); ``False`` if it existed."""
        return self._run(ops.make_dir(self._state, path, parents=parents))

    def remove_dir(self, path: str, *, missing_ok: bool = False) -> None:
        """Delete an empty directory."""
        self._run(ops.remove_dir(self._state, path, missing_ok=missing_ok))

    def delete_file(self, path: str, *, missing_ok: bool = False) -> None:
        """Delete a file."""
        self._run(ops.delete_file(self._state, path, missing_ok=missing_ok))

    def copy_file(self, source: str, target: str) -> None:
        """Copy a file on the control (target ending in ``/`` keeps the name)."""
        self._run(ops.copy_file(self._state, source, target))

    def move_file(self, source: str, target: str) -> None:
        """Move or rename a file on the control."""
        self._run(ops.move_file(self._state, source, target))

    def write_file(
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
                self._run(
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
                self._reconnect()  # the control drops the partial file; start again
        if self.serial is not None:
            if mode:
                self._check_serial_size(remote, len(data), upload=True)
            else:
                self._check_serial_text(remote, data)

    def _attempts(self) -> int:
        # Over serial a transfer whose telegram the link gave up is started once more over a
        # fresh link (docs/lsv2-serial.md, "Telegram size"); over TCP a failure is final.
        return 1 if self.serial is None else self.serial_attempts

    def _reconnect(self) -> None:
        driver, self._driver = self._driver, None
        if driver is not None:
            driver.close()
        self.serial_restarts += 1
        self.connect()

    def _serial_fault(self, remote: str, what: str, *, upload: bool) -> TransferError:
        if upload:
            # no damaged program left on the control
            with contextlib.suppress(DncError):
                self.delete_file(remote)
        return TransferError(f"{what}: the serial line let an error through; try again")

    def _check_serial_size(self, remote: str, size: int, *, upload: bool) -> None:
        # Serial LSV2's XOR block check cannot see a lost NUL byte (docs/lsv2-serial.md, "What
        # the block check cannot see"): compare the sizes of binary files at both ends.
        info = self.file_info(remote)
        if info is not None and info.size == size:
            return
        got = "no such file" if info is None else f"{info.size} bytes"
        what = f"{remote}: {got} on the control, {size} bytes here"
        raise self._serial_fault(remote, what, upload=upload)

    def _check_serial_text(self, remote: str, data: bytes) -> None:
        # Text has no size to compare as is: the control writes its own line end for every
        # NUL that ended a line on the wire. The size it reports is that of CR LF line ends
        # (docs/lsv2-serial.md, "Every text upload verified"); any other size is settled by
        # reading the file back, NUL line ends and all, and comparing it with what was sent.
        self.serial_checks += 1
        info = self.file_info(remote)
        if info is not None and info.size == text_size(data):
            return
        if info is not None:
            self.serial_readbacks += 1
            sent = to_wire_ascii(data)
            back = self.read_file(remote, binary=False, line_end=b"\0")
            if back == sent:
                return  # a control that stores other line ends: the text itself is exact
            what = f"{remote} reads back {len(back)} bytes on the control, {len(sent)} sent"
        else:
            what = f"{remote}: no such file on the control after the upload"
        raise self._serial_fault(remote, what, upload=True)

    def read_file(
        self, remote: str, *, binary: bool | None = None, line_end: bytes = b"\r\n"
    ) -> bytes:
        """Contents of ``remote``; ``binary=None`` picks the mode by file type."""
        mode = is_binary_name(remote) if binary is None else binary
        parts: list[bytes] = []
        self._run(ops.download(self._state, remote, parts.append, binary=mode, line_end=line_end))
        return b"".join(parts)

    def upload(
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
        self.write_file(target, data, binary=binary, overwrite=overwrite, progress=progress)
        return len(data)

    def download(
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
                    count = self._run(
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
                        self._check_serial_size(remote, count, upload=False)
                    return count
            except SerialLinkError:
                if attempt >= self._attempts():
                    raise
                self._reconnect()  # no partial file was kept; fetch it again
        raise AssertionError("unreachable")

    # -- machine state ---------------------------------------------------------------------

    def date_time(self) -> datetime:
        """The control's clock."""
        return self._run(ops.date_time(self._state))

    def run_info(self, selector: int) -> RunInfoValue:
        """Raw ``R_RI`` access by selector, decoded."""
        return self._run(ops.run_info(self._state, selector))

    def execution_mode(self) -> ExecutionMode:
        """Operating mode (manual, MDI, single block, automatic ...)."""
        return self._run(ops.execution_mode(self._state))

    def program_state(self) -> ProgramState:
        """Program state (started, stopped, idle ...)."""
        return self._run(ops.program_state(self._state))

    def selected_program(self) -> SelectedProgram:
        """Selected main program, executing (called) program and line: the program stack."""
        return self._run(ops.selected_program(self._state))

    def overrides(self) -> Overrides:
        """Feed, spindle and rapid overrides."""
        return self._run(ops.overrides(self._state))

    def axes_position(self) -> AxesPositions:
        """Current axis positions."""
        return self._run(ops.axes_position(self._state))

    def axes_names(self) -> AxesNames:
        """Physical axis names."""
        return self._run(ops.axes_names(self._state))

    def axes_config(self) -> AxesConfig:
        """Axis configuration."""
        return self._run(ops.axes_config(self._state))

    def current_tool(self) -> ToolInfo:
        """The tool in the spindle (iTNC 530)."""
        return self._run(ops.current_tool(self._state))

    def nc_errors(self) -> list[NcError]:
        """All pending NC error messages (iTNC 530)."""
        return self._run(ops.nc_errors(self._state))

    def uptimes(self) -> Uptimes:
        """NC, machine, run-time and spindle time counters."""
        return self._run(ops.uptimes(self._state))

    # -- PLC, data paths, machine parameters -----------------------------------------------

    def read_plc(self, operand: str | PlcOperand, count: int = 1) -> list[PlcValue]:
        """Read PLC operands by notation, e.g. ``read_plc("M100", 8)`` or ``"W4"``."""
        return self._run(ops.read_plc(self._state, operand, count))

    def read_plc_memory(self, memory: MemoryType, index: int, count: int = 1) -> list[PlcValue]:
        """Read ``count`` elements of ``memory`` starting at element ``index``."""
        return self._run(ops.read_plc_memory(self._state, memory, index, count))

    def read_data_path(self, path: str) -> int | float | str | bool:
        """Read a value by data path, e.g. ``/TABLE/TOOL/T/1/L`` (iTNC 530)."""
        return self._run(ops.read_data_path(self._state, path))

    def read_machine_parameter(self, name: str) -> str:
        """A machine parameter's value as text."""
        return self._run(ops.read_machine_parameter(self._state, name))

    def write_machine_parameter(self, name: str, value: str, *, temporary: bool = False) -> None:
        """Write a machine parameter (needs ``safe_mode=False``)."""
        self._run(ops.write_machine_parameter(self._state, name, value, temporary=temporary))

    # -- keyboard, screen, logs, tables, scope ---------------------------------------------

    def lock_keyboard(self, locked: bool = True) -> None:
        """Lock or unlock the control's keyboard (needs ``safe_mode=False``)."""
        self._run(ops.lock_keyboard(self._state, locked))

    def send_key(self, code: int, *, lock: bool = True) -> None:
        """Emulate a key press (needs ``safe_mode=False``); see ``KeyCode``/``OldKeyCode``."""
        self._run(ops.emulate_key(self._state, code, lock=lock))

    def screen_dump(self, local: PathLike | None = None) -> bytes:
        """Screenshot of the control as BMP; also saved to ``local`` (BMP, or PNG by suffix)."""
        bmp = self._run(ops.screen_dump(self._state, stamp=datetime.now(UTC)))
        if local is not None:
            data = image_bytes(bmp, local)
            with AtomicFile(local) as out:
                out.write(data)
        return bmp

    def operations_log(
        self, local: PathLike | None = None, *, since: datetime, name: str = "operation.log"
    ) -> bytes:
        """Have the control generate its operations log since ``since``; return (and save)."""
        data = self._run(ops.operations_log(self._state, since=since, name=name))
        if local is not None:
            with AtomicFile(local) as out:
                out.write(data)
        return data

    def read_table(self, remote: str | None = None) -> Table:
        """Parse a table file (default: the family's tool table)."""
        path = remote if remote is not None else ops.table_paths(self.family)[0]
        return self._run(ops.read_table(self._state, path))

    def write_table(self, remote: str, table: Table) -> None:
        """Write a table file (needs ``safe_mode=False``)."""
        self._run(ops.write_table(self._state, remote, table))

    def scope_channels(self) -> list[ScopeChannel]:
        """Remote-scope channels (iTNC 530)."""
        return self._run(ops.scope_channels(self._state))

    def scope_record(
        self, signals: list[ScopeSignal], *, interval: int = 21000, blocks: int = 1
    ) -> ScopeRecording:
        """Record ``blocks`` × 32 samples of ``signals`` every ``interval`` µs (iTNC 530)."""
        return self._run(ops.scope_record(self._state, signals, interval=interval, blocks=blocks))
