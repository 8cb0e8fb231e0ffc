"""Alerts by e-mail and webhook: which states and job ends raise one (:mod:`.rules`), what an
alert says and how it gets there (:mod:`.delivery`), and the component that watches the event
bus and sends each (:mod:`.component`).

It may import the packages under it; its settings are :mod:`opendnc.server.config.alerts`.
"""
