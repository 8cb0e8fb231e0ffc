"""Reports built from utilization: the shift report (:mod:`.shift`), its page
(:mod:`.routes`) and its e-mail at each shift's end (:mod:`.mail`) (docs/dashboard.md#shift-report).

It stands above the pages, whose templates and helpers it renders with (the page and the
e-mail alike), and may import every package of the server; only ``app.py`` imports it.
"""
