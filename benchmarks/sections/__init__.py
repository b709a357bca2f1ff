"""The sections of ``quadsitl bench``, one module each; their registry is :mod:`benchmarks.registry`."""
