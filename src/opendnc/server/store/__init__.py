"""The database: engines, migrations and the tables (:mod:`.db`, :mod:`.models`), the append-only
audit trail (:mod:`.audit`), whether the database answers (:mod:`.health`), the wake-ups
between servers on one PostgreSQL (:mod:`.notify`) and the claims that let one server do a duty
once (:mod:`.claims`).

It may import :mod:`opendnc.server.core` only.
"""
