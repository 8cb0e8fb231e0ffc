"""A virtual control's FTP folder: what an Okuma, a Mazak or a Siemens control offers when it
takes programs over FTP (docs/files.md#ftp-folder-on-the-control), on loopback, for
``opendnc sim ftp``, ``sim fleet --ftp N``, the tests and the demo.

It is pyftpdlib serving one account whose root is the control's program folder
(:mod:`opendnc.ftpserve`); a program the server stores there is in the control's memory.
"""

from __future__ import annotations

from pathlib import Path

from opendnc.ftpserve import Account, FtpFolders

__all__ = ["VirtualFtpFolder"]


class VirtualFtpFolder(FtpFolders):
    """The FTP folder ``folder`` of one virtual control, login ``user``/``password``."""

    def __init__(
        self,
        folder: Path,
        *,
        user: str = "dnc",
        password: str = "dnc",
        host: str = "127.0.0.1",
        port: int = 0,
    ) -> None:
        super().__init__(
            [Account(user, password, folder)],
            host=host,
            port=port,
            banner="opendnc virtual control FTP ready.",
        )
        self.folder = folder
        self.user = user
        self.password = password
