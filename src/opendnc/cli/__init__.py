"""The ``opendnc`` command line (typer + rich)."""
