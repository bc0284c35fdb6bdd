"""Command-line client of the CPCC REST API for customers (``cpcc``).

Standard library only: it runs wherever Python 3.11 does, without Django or the platform.
"""

__all__ = ["ApiError", "Client", "Unreachable"]

from cpcc_client.client import ApiError, Client, Unreachable
