"""The machines' cards: built from each machine's live state and what the card-jobs action
(:func:`opendnc.server.actions.machines.card_jobs`) tells of its jobs, and kept up to date by
the live stream (:mod:`.live`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import tzinfo

from opendnc.server.actions.machines import CardJobs, LastJob, card_jobs
from opendnc.server.web import render
from opendnc.server.web.pages.base import Page

__all__ = ["CardCache", "cards"]


def _build(page: Page, names: list[str], facts: CardJobs, zone: tzinfo) -> list[render.Card]:
    states = page.parts.machines.machines
    out = []
    for name in names:
        job_id = states[name].job_id
        label = facts.labels.get(job_id, "") if job_id is not None else ""
        out.append(
            render.card(
                render.Seen.of(states[name], label),
                queued=facts.queued.get(name, 0),
                last_job=facts.last.get(name),
                zone=zone,
            )
        )
    return out


def cards(page: Page, names: list[str] | None = None) -> list[render.Card]:
    """The cards of ``names`` (all the machines by default), in that order."""
    states = page.parts.machines.machines
    wanted = names if names is not None else list(states)
    running = [i for i in (states[n].job_id for n in wanted) if i is not None]
    facts = card_jobs(page.svc, page.who, labels=running, last_of=wanted)
    return _build(page, wanted, facts, page.parts.calendar.zone)


@dataclass
class CardCache:
    """What a live stream keeps between its cards: the labels of running jobs (they do not
    change), and each machine's last finished job (read again only when one of its jobs
    ended: the machines in ``stale``)."""

    stale: set[str]
    labels: dict[int, str] = field(default_factory=dict)
    last: dict[str, LastJob] = field(default_factory=dict)

    def cards(self, page: Page, names: list[str], zone: tzinfo) -> list[render.Card]:
        """The cards of ``names``, asking only for what this cache does not hold."""
        states = page.parts.machines.machines
        new = [states[n].job_id for n in names if states[n].job_id not in self.labels]
        stale = [n for n in names if n in self.stale]
        found = card_jobs(
            page.svc, page.who, labels=[i for i in new if i is not None], last_of=stale
        )
        self.labels.update(found.labels)
        for n in stale:
            self.last.pop(n, None)
        self.last.update(found.last)
        self.stale.difference_update(stale)
        return _build(page, names, CardJobs(found.queued, self.labels, self.last), zone)
