"""The words of a job: what it does (:class:`JobKind`) and where it is (:class:`JobState`).

They live in the core because the job events carry them (:mod:`.events`) as well as the
queue's table (``store.models``, which re-exports them): one vocabulary from the row to the
page.
"""

from __future__ import annotations

import enum

__all__ = ["JobKind", "JobState"]


class JobKind(enum.StrEnum):
    """What a job does on its machine."""

    SEND = "send"  # load one program version into the control
    RECEIVE = "receive"  # take a program from the control into the inbox
    BACKUP = "backup"  # LSV2: copy a folder of the control
    DRIPFEED = "dripfeed"  # stream a program while the control runs it
    DELETE = "delete"  # remove a file from the control
    PUT_FILE = "put_file"  # write a library version to a path on the control (file browser)
    REPORT = "report"  # a short program telling the operator what the server did


class JobState(enum.StrEnum):
    """Where a job is; only the queue module moves a job between these."""

    QUEUED = "queued"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"
    INTERRUPTED = "interrupted"  # the server or the link stopped while it ran

    @property
    def finished(self) -> bool:
        """True once the job will not run again by itself."""
        return self not in (JobState.QUEUED, JobState.RUNNING)
