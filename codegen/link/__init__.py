"""Streaming: the link between the host and a streaming firmware (protocol.py), the host's side of it (host.py),
the ring buffer's fill, planned before anything is sent (ring.py), line faults for the tests (faults.py), a real
serial port (serial_port.py), and the tune firmware's frames (tune.py)."""
