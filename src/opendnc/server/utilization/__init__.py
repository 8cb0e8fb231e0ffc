"""Utilization: how long each machine spent in each state, with parts, runs, stops and alarms,
per shift, day or week of the shop's calendar, read from the stored status timeline
(docs/dashboard.md#utilization).

What it promises: every figure comes from the stored samples through the one reader of stored
state words (:func:`opendnc.server.core.state.from_stored`), so utilization and the status
timeline never disagree about the same sample; finished hours and days are summed once and a
question is answered from those sums (the same figures as reading every sample).

Its modules, lowest first:

* :mod:`.sums`: the arithmetic and the definitions, no database.
* :mod:`.days`: the local days summed from the hours (``utilization_days``, weeks).
* :mod:`.collect`: reads the samples and summed hours from the database; :func:`.collect.report`.
* :mod:`.answer`: parameters parsed, the report as JSON or CSV (the API's and the page's).
* :mod:`.component`: the ``utilization`` component summing finished hours while the server runs.
* :mod:`.routes`: ``GET /api/utilization``.

What it may import: the database store (:mod:`opendnc.server.store`), the state classifier
(:mod:`opendnc.server.core.state`), the shop's configuration and calendar
(:mod:`opendnc.server.config.shop`, :mod:`opendnc.server.core.shifts`), the components core, and for
:mod:`.routes` only the pieces every API route shares (:mod:`opendnc.server.http.shared`).
Never ``web/`` and never another module of API routes (``server/http/api.py``): the pages import
this package, not the other way round. ``tests/server/test_utilization_layers.py`` holds it
to that.
"""
