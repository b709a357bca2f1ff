"""autopilot: the discrete-time backstepping controller (paper eqs 18–33, corrected), the PD
baseline, the gain checker for conditions (41)–(44) and, later, the autopilot process.

Sees the vehicle only through the state it is given (never the plant's internals).
"""
