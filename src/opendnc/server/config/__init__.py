"""``shop.toml`` as typed, validated dataclasses: the shop and its machines (:mod:`.shop`,
each machine through its kind's schema), the ``[alerts]`` table (:mod:`.alerts`) and the
``[clients]`` limits (:mod:`.clients`).

It may import :mod:`opendnc.server.core` and :mod:`opendnc.server.kinds` (for the machines'
schemas), nothing above.
"""
