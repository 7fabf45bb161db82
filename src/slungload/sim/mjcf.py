"""The MuJoCo model of vehicle + cable + load, written as MJCF from a ``SimConfig``.

Two free bodies: the quadrotor (a rigid body with the Intel Aero's mass and inertia) and the
cube. The cable is a spatial tendon from a site under the vehicle to a site on the cube's top
face, ``limited`` to [0, string length]: it pulls only when taut (it can go slack) and a soft
limit lets it stretch a little. Contacts are disabled (the flights stay clear of the floor and
the cable cannot wrap). Thrust is a site actuator along body z with a first-order filter (the
thrust lag); the body-rate loop is three site actuators producing ``k (w_cmd - w)`` torques about
the body axes, their command low-passed by the motor lag. Aerodynamic forces, wind and downwash
are applied from Python through ``xfrc_applied`` (see ``aero.py``).
"""

from __future__ import annotations

import numpy as np

from .config import SimConfig

QUAD = "quad"
LOAD = "load"
CABLE = "cable"
THRUST_ACTUATOR = 0  # index of the thrust actuator; rate actuators follow (x, y, z)


def vec(values) -> str:
    """Numbers as an MJCF attribute's text: space-separated, 9 significant digits."""
    return " ".join(f"{float(v):.9g}" for v in values)


def options(cfg: SimConfig) -> str:
    """The ``<option>`` block both families' models share: the timestep, gravity, the
    implicit-fast integrator, contacts off (nothing but the arena's guard ends a flight)."""
    gravity = f"0 0 {-cfg.gravity:.9g}"
    return f"""<option timestep="{cfg.timestep:.9g}" gravity="{gravity}" integrator="implicitfast">
    <flag contact="disable"/>
  </option>"""


def cable_solref(cfg: SimConfig) -> tuple[float, float]:
    """``solreflimit`` of the cable tendon.

    Elastic cable: MuJoCo's direct form (-stiffness, -damping) in acceleration units, i.e. per
    unit effective mass of the constraint. With impedance 0.5 (``cable_solimp``) MuJoCo's
    static stretch came out at twice m g / (k / m_eff) in a hanging test, so the load mass is
    used as the effective mass and the value halved; ``tests/test_sim.py`` checks that the
    hanging load stretches the cable by mL g / k. Rigid cable: a stiff time constant of two
    timesteps, critically damped.
    """
    if not cfg.effects.cable_stretch:
        return (2.0 * cfg.timestep, 1.0)
    m_eff = 2.0 * cfg.load_mass
    return (-cfg.cable_stiffness / m_eff, -cfg.cable_damping / m_eff)


def cable_solimp(cfg: SimConfig) -> tuple[float, float, float]:
    """``solimplimit`` of the cable: impedance 0.5 for the elastic cable.

    MuJoCo blends the reference acceleration and the unconstrained one with the impedance d,
    so a steady pull stretches the constraint by (1 - d) / d times its nominal compliance;
    d = 0.5 makes the static stretch m g / k of a spring of stiffness k.
    """
    if not cfg.effects.cable_stretch:
        return (0.95, 0.95, 0.001)
    return (0.5, 0.5, 0.001)


def build_mjcf(cfg: SimConfig, thrust_offset: np.ndarray | None = None) -> str:
    """MJCF text of the system hovering at ``cfg.hover_z`` with the load hanging still.

    thrust_offset (2,): m, x-y position of the thrust centre relative to the centre of mass.
    """
    off = np.zeros(2) if thrust_offset is None else np.asarray(thrust_offset, dtype=float)
    half = 0.5 * cfg.load_size
    z_load = cfg.hover_z - cfg.cable_length
    inertia_load = cfg.load_mass * cfg.load_size**2 / 6.0
    bw = np.asarray(cfg.rate_bandwidth, dtype=float)
    inertia = np.asarray(cfg.inertia_quad, dtype=float)
    if cfg.effects.rate_loop:
        rate_gain = inertia * bw  # N m / (rad/s): closed-loop pole at -bw for a rigid body
        rate_dyn = f'dyntype="filter" dynprm="{cfg.motor_tau:.9g}"'
    else:
        rate_gain = np.zeros(3)  # the flight loop sets the body rates directly
        rate_dyn = 'dyntype="none"'
    if cfg.effects.thrust_lag:
        thrust_dyn = f'dyntype="filter" dynprm="{cfg.thrust_tau:.9g}"'
    else:
        thrust_dyn = 'dyntype="none"'
    solref = cable_solref(cfg)
    rate_actuators = "\n".join(
        f'    <general name="rate_{axis}" site="thrust" gear="0 0 0 {vec(np.eye(3)[i])}" '
        f'{rate_dyn} gainprm="{rate_gain[i]:.9g}" biastype="affine" '
        f'biasprm="0 0 {-rate_gain[i]:.9g}"/>'
        for i, axis in enumerate("xyz")
    )
    return f"""<mujoco model="slungload">
  {options(cfg)}
  <worldbody>
    <body name="{QUAD}" pos="0 0 {cfg.hover_z:.9g}">
      <freejoint/>
      <inertial pos="0 0 0" mass="{cfg.mass_quad:.9g}" diaginertia="{vec(inertia)}"/>
      <site name="thrust" pos="{off[0]:.9g} {off[1]:.9g} 0"/>
      <site name="attach" pos="0 0 {-cfg.attach_below:.9g}"/>
    </body>
    <body name="{LOAD}" pos="0 0 {z_load:.9g}">
      <freejoint/>
      <inertial pos="0 0 0" mass="{cfg.load_mass:.9g}" diaginertia="{vec([inertia_load] * 3)}"/>
      <site name="hook" pos="0 0 {half:.9g}"/>
    </body>
  </worldbody>
  <tendon>
    <spatial name="{CABLE}" limited="true" range="0 {cfg.string_length:.9g}"
             solreflimit="{vec(solref)}" solimplimit="{vec(cable_solimp(cfg))}">
      <site site="attach"/>
      <site site="hook"/>
    </spatial>
  </tendon>
  <actuator>
    <general name="thrust" site="thrust" gear="0 0 1 0 0 0" {thrust_dyn} gainprm="1"/>
{rate_actuators}
  </actuator>
</mujoco>
"""
