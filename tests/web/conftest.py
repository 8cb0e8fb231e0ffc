"""The pages' tests share the server tests' database fixture (``db_url``: each backend)."""

from tests.server.conftest import db_url

__all__ = ["db_url"]
