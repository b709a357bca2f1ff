"""sitl: the simulated quadrotor (the truth). Dynamics of paper eqs (2)–(7) in NED/FRD, actuator
models, integrators, the ground plane and, later, the plant process and its MAVLink link.

Owns no controller: the closed loop of plant and autopilot is composed once, in :mod:`groundstation.vehicle`.
"""
