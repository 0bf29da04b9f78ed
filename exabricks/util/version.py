"""The version of exabricks (the package's `__version__`, read by the build backend
from here): written into every output's provenance and cache key."""

__version__ = "0.1.0"
