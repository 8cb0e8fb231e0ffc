"""The JSON API under ``/api/`` and what every request passes through: the routes
(:mod:`.api`, :mod:`.dprnt`, :mod:`.utilization`, :mod:`.alerts`), the pieces they share
(:mod:`.shared`, :mod:`.deps`, :mod:`.sessions`), the answers for errors (:mod:`.edge`),
limits on clients (:mod:`.limits`, :mod:`.clients`), event streams (:mod:`.streams`) and large
downloads (:mod:`.downloads`).

The routes call the actions (:mod:`opendnc.server.actions`); the pages (``web/``) sit above and
this package never imports them.
"""
