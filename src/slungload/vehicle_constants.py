"""The discrete model's constants as one tuple of numbers, torch-free (the onboard path reads
them): ``VehicleConstants``, and the ratios to a reference that a network conditioned on its
constants sees (``constant_ratios``). ``physics`` re-exports ``VehicleConstants``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple, Union

from .config import CONDITIONED, VehicleParams

if TYPE_CHECKING:
    import torch
    from torch import Tensor

Constant = Union[float, "Tensor"]  # a float, a 0-d tensor, or one value per window (B,)


class VehicleConstants(NamedTuple):
    """The constants ``step`` reads: the fields of ``config.VehicleParams``, in its order and
    units (a test holds the two equal), as floats (``of``), fitted tensors, or one value per
    window (``stack``)."""

    mass_quad: Constant
    mass_load: Constant
    cable_length: Constant
    load_damping: Constant
    dt: Constant
    gravity: Constant
    thrust_gain: Constant

    @classmethod
    def of(cls, params: VehicleParams | VehicleConstants) -> VehicleConstants:
        """One set as python floats (any object with ``VehicleParams``' attributes)."""
        return cls(*(float(getattr(params, name)) for name in cls._fields))

    @classmethod
    def stack(
        cls,
        params: Sequence[VehicleParams],
        *,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> VehicleConstants:
        """One set per window: each constant a tensor (B,) of the B ``params`` in order (dtype:
        torch's default; give the states' dtype to keep theirs)."""
        import torch  # only here: the rest of this module is torch-free

        if not params:
            raise ValueError("VehicleConstants.stack needs at least one set of constants")
        return cls(
            *(
                torch.tensor([float(getattr(p, name)) for p in params], dtype=dtype, device=device)
                for name in cls._fields
            )
        )


def constant_ratios(params, reference) -> list:
    """f's ``config.CONDITIONED`` constants as a network with ``constants_input`` sees them:
    each params' / reference's - 1 (0 at the network's own), floats or tensors (B,) as params
    holds them (``VehicleParams`` or ``VehicleConstants`` each). One definition for the eager
    network and the compiled paths."""
    return [getattr(params, name) / float(getattr(reference, name)) - 1 for name in CONDITIONED]
