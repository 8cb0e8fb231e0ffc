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
Its route, ``GET /api/utilization``, is :mod:`opendnc.server.http.utilization`.

What it may import: the core (the state classifier, the shop's calendar, components), the
database store and the shop's configuration (core, store, kinds, config), never the routes
(``http/``) or the pages (``web/``), which import it. ``tests/server/test_layers.py`` holds
it to that.
"""
