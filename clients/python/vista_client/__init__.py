"""vista's Python SDK: ``VistaClient`` for the whole REST API, ``Headset`` for a headset's
offline copy of an inspection and its sync."""

from vista_client.client import VistaClient, VistaError
from vista_client.headset import Headset, HeadsetOffline, StateMismatch

__all__ = ["Headset", "HeadsetOffline", "StateMismatch", "VistaClient", "VistaError"]
