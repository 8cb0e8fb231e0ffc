"""The database: engines, migrations and the tables (:mod:`.db`, :mod:`.models`), the append-only
audit trail (:mod:`.audit`), whether the database answers (:mod:`.health`) and the wake-ups
between servers on one PostgreSQL (:mod:`.notify`).

It may import :mod:`opendnc.server.core` only.
"""
