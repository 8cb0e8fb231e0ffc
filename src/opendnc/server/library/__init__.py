"""The program library: versions addressed by SHA-256 and their approval states
(:mod:`.versions`), the watched library folder (:mod:`.watcher`), the program check of a
version (:mod:`.checks`), a program's title (:mod:`.titles`) and the inbox of programs
received from the controls (:mod:`.inbox`).

It may import core, store, kinds and config.
"""
