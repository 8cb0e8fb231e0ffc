"""G-code program text shared by the virtual Haas and the dry-run checker.

:mod:`opendnc.gcode.program` parses Haas / Fanuc macro-B blocks and evaluates macro
expressions; it does no execution and no I/O. The virtual Haas (:mod:`opendnc.sim.haas`)
runs the parsed blocks against its machine model, the checker (:mod:`opendnc.nccheck`) runs
them as a dry run.
"""
