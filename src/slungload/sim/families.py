"""One flight's plant from its config's family (``SimConfig.family``, ``config.FAMILIES``)."""

from __future__ import annotations

from .chain import ChainPlant
from .config import SimConfig
from .plant import Plant, PlantParams

# family -> the class that simulates it (each meets ``Plant``'s interface)
PLANT_CLASSES: dict[str, type] = {"tendon": Plant, "chain": ChainPlant}


def make_plant(cfg: SimConfig, params: PlantParams | None = None) -> Plant | ChainPlant:
    """The plant of ``cfg``'s family, starting in hover with the load hanging still."""
    return PLANT_CLASSES[cfg.family](cfg, params)
