"""``quadsitl bench``: speed measured against this machine's own limits (see bench.py)."""
