"""The plant: actuators, rigid-body dynamics, integrator and ground plane, one control period at a time.

Pure computation, no I/O. ``Plant.step(commanded_forces)`` advances the truth state by the control
period T, using ``substeps`` integration steps with the inputs held (zero-order hold).

Ground plane (altitude 0, NED z = 0): after every sub-step, a vehicle at or below the ground that is
not climbing is put on it (z = 0) and stopped (velocity zero: ground friction). A vehicle whose
thrust does not lift it therefore rests on the ground, and nothing falls through. A climb starting
from the ground is not touched, so the paper's experiment is unaltered by starting on the ground.
"""

from __future__ import annotations

from quadsitl.config import Preset
from quadsitl.frames import wrap_pi
from quadsitl.mixer import forces_to_inputs, residual_rotor_speed
from quadsitl.state import Inputs, VehicleState
from sitl.actuators import Actuators, Forces
from sitl.dynamics import derivatives
from sitl.integrators import INTEGRATORS


def initial_state(preset: Preset) -> VehicleState:
    """The preset's initial state: at rest, at the given altitude and attitude."""
    i = preset.initial
    return VehicleState(z=-i.altitude, roll=i.roll, pitch=i.pitch, yaw=i.yaw)


class Plant:
    """The simulated quadrotor of a preset.

    Attributes after each step: ``state`` (VehicleState), ``forces`` (the mean motor forces applied
    over the last sub-step [N]), ``inputs`` (u1..u4 they make, eq (8)), ``omega_r`` [rad/s],
    ``on_ground`` (bool), ``time`` [s].
    """

    def __init__(self, preset: Preset, integrator: str | None = None, substeps: int | None = None) -> None:
        self.params = preset.vehicle
        self.period = preset.sim.period
        name = integrator or preset.sim.integrator
        if name not in INTEGRATORS:
            raise ValueError(f"integrator {name!r}: expected one of {', '.join(INTEGRATORS)}")
        self.integrate = INTEGRATORS[name]
        self.substeps = substeps or preset.sim.substeps
        self.actuators = Actuators(preset.actuators)
        self.state = initial_state(preset)
        self.forces: Forces = (0.0, 0.0, 0.0, 0.0)
        self.inputs = Inputs()
        self.omega_r = 0.0
        self.time = 0.0
        self.on_ground = self.state.z >= 0.0

    def step(self, commanded: Forces, omega_r: float | None = None) -> VehicleState:
        """Advance one control period under the commanded motor forces [N].

        ``omega_r`` overrides the residual rotor speed Ωr that eqs (5)–(6) use (the default computes it
        from the applied forces); tests use it to give the plant the Ωr the controller assumed.
        """
        p = self.params
        h = self.period / self.substeps
        d_over_b, b = p.d_over_b, p.thrust_factor
        s: tuple[float, ...] = self.state
        for _ in range(self.substeps):
            forces = self.actuators.advance(commanded, h)
            u = forces_to_inputs(forces, d_over_b)  # eq (8)
            wr = residual_rotor_speed(forces, b) if omega_r is None else omega_r

            def f(x: tuple[float, ...], u: Inputs = u, wr: float = wr) -> tuple[float, ...]:
                return derivatives(x, u, wr, p)

            s = self.integrate(f, s, h)
            s = self._ground(s)
        self.forces, self.inputs, self.omega_r = forces, u, wr
        self.state = VehicleState(*s[:8], wrap_pi(s[8]), *s[9:])
        self.time += self.period
        return self.state

    def _ground(self, s: tuple[float, ...]) -> tuple[float, ...]:
        if s[2] >= 0.0 and s[5] >= 0.0:  # at/below ground and not climbing (NED: z, vz down)
            self.on_ground = True
            return (s[0], s[1], 0.0, 0.0, 0.0, 0.0, *s[6:])
        self.on_ground = False
        return s
