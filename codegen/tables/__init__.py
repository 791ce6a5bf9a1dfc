"""The tables the player plays: rate runs, records, the byte format, and the twin with its checks."""
