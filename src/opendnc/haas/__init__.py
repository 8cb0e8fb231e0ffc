"""Haas controls: DPRNT (:mod:`.dprnt`, :mod:`.listen`), MDC Q/E commands (:mod:`.mdc`,
:mod:`.mdc_client`), a program runner (:mod:`.program`, :mod:`.machine`, :mod:`.runner`) and
Net Share push (:mod:`.share`)."""
