"""The server's small core, which every other part of the server builds on: components and
their start order (:mod:`.components`), the event bus and its typed events (:mod:`.events`),
the status a control reports (:mod:`.status`) and the one classifier of machine states
(:mod:`.state`), the server's errors, the configuration's key vocabulary, the shop's calendar,
and the folders the net share and a Haas NGC's connector read (local or SMB).

It may import the protocol layers (``opendnc.*`` outside ``opendnc.server``) and nothing else
of the server: every other package may import it.
"""
