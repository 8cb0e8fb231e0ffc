"""A virtual OPC UA server with the umati machine-tool objects (``opendnc sim opcua``)."""
