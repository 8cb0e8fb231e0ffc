"""What the server knows of each machine: its live state and errands (:mod:`.state`), its
stored status timeline (:mod:`.timeline`), its lease when several servers share one database
(:mod:`.leases`, fencing included), auto-receive from a control's folder
(:mod:`.autoreceive`) and DPRNT capture (:mod:`.dprnt_capture`).

It may import core, store, kinds, config and library.
"""
