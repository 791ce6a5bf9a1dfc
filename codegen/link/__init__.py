"""Streaming: the link between the host and a streaming firmware (protocol.py), the host's side of it (host.py),
and the ring buffer's fill, planned before anything is sent (ring.py)."""
