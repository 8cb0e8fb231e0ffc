"""The FTP server for boards that are FTP clients (Fanuc's Data Server and its like): one
account and one folder per ``[machines.files] mode = "ftp-server"`` machine
(docs/files.md#ftp-server-for-a-board); a component.

The board fetches the programs the server's sends put into its account's folder and stores
the ones it sends there; the machine's ``files`` connector writes and reads that folder
directly, and auto-receive watches it like any other folder. The server listens only while
the component runs (:mod:`opendnc.ftpserve`, a thread of its own).

Which accounts open here: a server alone opens every such machine's. In a cluster the board
reaches one host, and the folder is on that host's disk, so a machine of this mode is pinned
to one server (``servers = ["dnc-1"]``, checked when the server is built,
:func:`accounts_for`) and only that server opens its account; the cluster's leases then
always give it that machine, and the sends are written where the board looks.
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

from opendnc.ftpserve import Account, FtpFolders
from opendnc.server.config.ftp_server import FtpServerConfig
from opendnc.server.core.configkeys import ConfigError
from opendnc.server.kinds.base import MachineConfig

__all__ = ["FtpServer", "accounts_for"]

log = logging.getLogger(__name__)


def accounts_for(
    machines: tuple[MachineConfig, ...], server: str, clustered: bool
) -> list[Account]:
    """The accounts server ``server`` opens; :class:`ConfigError` for a machine of this mode
    a cluster could hand to another server than the one its board reaches."""
    accounts = []
    for i, machine in enumerate(machines):
        files = machine.files
        if files is None or files.mode != "ftp-server":
            continue
        if clustered and len(machine.servers) != 1:
            raise ConfigError(
                f"machines[{i}].servers",
                "an ftp-server machine in a cluster is pinned to the one server its board "
                'reaches: servers = ["NAME"]',
            )
        if machine.servers and server not in machine.servers:
            continue  # another server's board
        accounts.append(Account(files.user, files.password, Path(files.folder)))
    return accounts


class FtpServer:
    """Listens for the boards while the server runs."""

    name = "ftp-server"
    needs: tuple[str, ...] = ()

    def __init__(self, config: FtpServerConfig, accounts: list[Account]) -> None:
        self.config = config
        self.accounts = accounts
        self.folders: FtpFolders | None = None

    @property
    def port(self) -> int:
        """The port it listens on (the configured one, or the one picked for 0)."""
        return self.folders.port if self.folders is not None else self.config.port

    async def start(self) -> None:
        """Listen (a port taken is a :class:`~opendnc.errors.TransportError` at start)."""
        folders = FtpFolders(
            self.accounts,
            host=self.config.host,
            port=self.config.port,
            passive_ports=self.config.passive_ports,
        )
        self.folders = await asyncio.to_thread(folders.start)
        log.info(
            "FTP server for %d board(s) on %s:%d",
            len(self.accounts),
            self.config.host,
            folders.port,
        )

    async def stop(self) -> None:
        """Stop listening and drop the boards' sessions."""
        folders, self.folders = self.folders, None
        if folders is not None:
            await asyncio.to_thread(folders.close)
