"""The client side: the Python client, pneumactl, watch, plots and the client-side routines.

    from daemon.client import Client
"""
from daemon.client.client import Client, KeyRefused, RemoteError

__all__ = ["Client", "KeyRefused", "RemoteError"]
