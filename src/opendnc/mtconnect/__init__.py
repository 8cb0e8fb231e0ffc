"""Reading machines that already talk MTConnect: an agent's documents as typed data
(:mod:`.documents`, :mod:`.multipart`, :mod:`.device_state`, all sans-IO) and an asyncio
reader over httpx (:mod:`.reader`). Needs the ``server`` extra (lxml, httpx).

docs/mtconnect-input.md has the facts this package relies on.
"""
