"""Reports built from utilization: the shift report (:mod:`.shift`), its page
(:mod:`.routes`) and its e-mail at each shift's end (:mod:`.mail`) (docs/dashboard.md#shift-report).

May import :mod:`opendnc.server.utilization`, the configuration and the store; the page
module also the dashboard's rendering. Nothing in ``utilization`` imports this package.
"""
