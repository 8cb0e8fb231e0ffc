"""The open outputs: the machines' state for the rest of the factory over MQTT (:mod:`.mqtt`),
Sparkplug B (:mod:`.sparkplug`) and MTConnect SHDR (:mod:`.shdr`), in one vocabulary of data
items (:mod:`.items`), over one broker link kept up with backoff (:mod:`.broker`), and the
components that run them (:mod:`.parts`).

It may import the packages under it (core to fleet).
"""
