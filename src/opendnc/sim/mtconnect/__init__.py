"""A virtual MTConnect agent (:mod:`.agent`, its documents in :mod:`.documents`) and the
scripted machines behind it (:mod:`.machine`): a peer for the ``mtconnect`` machine kind's
tests, the fleet and the benchmarks (docs/mtconnect-input.md#the-virtual-agent)."""
