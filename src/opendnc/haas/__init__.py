"""Haas controls: DPRNT (:mod:`.dprnt`, :mod:`.listen`), MDC Q/E commands (:mod:`.mdc`,
:mod:`.mdc_client`), drip-feed (:mod:`.dnc`, :mod:`.modal`) and Net Share push (:mod:`.share`).

The G-code parser is :mod:`opendnc.gcode`; the virtual Haas (:mod:`opendnc.sim.haas`) runs it."""
