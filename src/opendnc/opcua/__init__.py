"""Reading machines that speak OPC UA with the umati machine-tool model (OPC 40501-1): the
names and wire values of that model as we use them (:mod:`.model`), shared by the ``opcua``
machine kind and the virtual server. Needs the ``server`` extra (asyncua).

docs/opcua-input.md has the facts this package relies on and says which are ours.
"""
