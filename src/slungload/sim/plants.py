"""Named plants: instances of the simulator's families (``SimConfig.family``), for ``--plant``.

Each is a vehicle with its cable and load, nominal constants only (flights still draw their
imperfections, wind and noise). The ``tendon`` instances vary today's simulator's vehicle; the
``chain`` family is structurally different (``sim/chain.py``). Vehicles span 0.5-2 kg, cables
0.5-1.5 m, loads 10-40 % of the vehicle, so that a result is not one vehicle's. Light: the
command line's help lists them without MuJoCo.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from .config import SimConfig

DEFAULT_PLANT = "default"


def _vehicle(
    base: SimConfig, mass: float, cable: float, load: float, arm: float, **more
) -> SimConfig:
    """``base`` with a vehicle of ``mass`` kg (inertia scaled from the default's by mass and
    arm length ``arm`` m), ``load`` kg on an effective cable of ``cable`` m, thrust up to 2.2x
    the weight, hovering ``cable`` + 0.8 m high."""
    ref = SimConfig()
    k = (mass / ref.mass_quad) * (arm / ref.chain.arm) ** 2
    inertia = tuple(round(k * i, 9) for i in ref.inertia_quad)
    max_thrust = round(2.2 * (mass + load) * ref.gravity, 3)
    cfg = replace(base, mass_quad=mass, inertia_quad=inertia, max_thrust=max_thrust,
                  hover_z=round(max(ref.hover_z, cable + 0.8), 3),
                  chain=replace(base.chain, arm=arm), **more)  # fmt: skip
    return cfg.with_load(load_mass=load, cable_length=cable)


_CHAIN = SimConfig(family="chain", load_size=0.08, attach_below=0.03)

# name -> (what it is, its config)
PLANTS: dict[str, tuple[str, Callable[[], SimConfig]]] = {
    DEFAULT_PLANT: ("tendon family: the 1.35 kg default vehicle, 0.1 kg on 0.7 m", SimConfig),
    "tendon-light": (
        "tendon family: 0.8 kg, 0.08 kg (10 %) on 0.5 m",
        lambda: _vehicle(SimConfig(), 0.8, 0.5, 0.08, 0.12),
    ),
    "tendon-heavy": (
        "tendon family: 2.0 kg, 0.5 kg (25 %) on 1.2 m",
        lambda: _vehicle(SimConfig(), 2.0, 1.2, 0.5, 0.2),
    ),
    "chain-light": (
        "chain family: 0.6 kg, 0.09 kg (15 %) on 0.5 m",
        lambda: _vehicle(_CHAIN, 0.6, 0.5, 0.09, 0.11),
    ),
    "chain": (
        "chain family: 1.2 kg, 0.3 kg (25 %) on 1.0 m",
        lambda: _vehicle(_CHAIN, 1.2, 1.0, 0.3, 0.16),
    ),
    "chain-heavy": (
        "chain family: 2.0 kg, 0.8 kg (40 %) on 1.5 m",
        lambda: _vehicle(_CHAIN, 2.0, 1.5, 0.8, 0.2),
    ),
}


def plant_config(name: str) -> SimConfig:
    """The named plant's config; an unknown name is a ``ValueError`` listing the known."""
    if name not in PLANTS:
        raise ValueError(f"unknown plant {name!r}; known: {list(PLANTS)}")
    return PLANTS[name][1]()
