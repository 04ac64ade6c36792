"""The unit tests. A package, so that test modules import the shared helpers with ``from .conftest import ...``."""
