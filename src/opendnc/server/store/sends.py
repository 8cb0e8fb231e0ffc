"""Whether this server put a file on a machine itself: what the net share's collect and the
auto-receive of a machine's folder ask before taking a file for the control's own work."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from opendnc.server.store.models import Job, JobKind, Program, ProgramVersion

__all__ = ["sent_by_us"]


def sent_by_us(session: Session, machine: str, name: str, digest: str) -> bool:
    """Whether a job of this server put exactly this file (name and content) on ``machine``:
    a send to a Haas NGC writes the program into the share the net share collects from, a
    send to a machine with a files table into the folder its auto-receive watches. The job's
    row is there from its claim on, before the file is written, so a look never sees the file
    first; a failed send that wrote it counts too."""
    found = session.scalar(
        select(Job.id)
        .join(ProgramVersion, Job.version_id == ProgramVersion.id)
        .join(Program, ProgramVersion.program_id == Program.id)
        .where(
            Job.machine == machine,
            Job.kind.in_((JobKind.SEND, JobKind.PUT_FILE)),
            Program.name == name,
            ProgramVersion.sha256 == digest,
        )
        .limit(1)
    )
    return found is not None
