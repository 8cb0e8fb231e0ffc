"""Where a Sparkplug B edge node keeps its ``bdSeq`` between restarts: the server's database.

The database is the one place a server keeps its state: it is there before the server starts
(the server does not start without it), it survives a new PC, and in a cluster each server's
node has its own row (docs/server.md#sparkplug-b).
"""

from __future__ import annotations

from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.store.models import SparkplugNode

__all__ = ["BD_SEQ_MODULO", "next_bd_seq"]

BD_SEQ_MODULO = 256
"""bdSeq counts 0..255 and then starts again at 0."""


def next_bd_seq(sessions: sessionmaker[Session], group: str, node: str) -> int:
    """Take the bdSeq of a new MQTT session of edge node ``group``/``node`` and store it.

    The first session ever is 0; each next one is the stored value plus one, modulo 256. It is
    stored before the connection is made, so a server that dies in a session starts its next
    one with a new number.
    """
    with sessions.begin() as session:
        row = session.get(SparkplugNode, (group, node), with_for_update=True)
        if row is None:
            session.add(SparkplugNode(group_id=group, node_id=node, bd_seq=0))
            return 0
        row.bd_seq = (row.bd_seq + 1) % BD_SEQ_MODULO
        return row.bd_seq
