"""groundstation: the operator side. Reference trajectories, the ``quadsitl`` command, loggers,
metrics, figures and reports. Owns no control law: it builds controllers from ``autopilot`` and
plants from ``sitl`` only to run them.
"""
