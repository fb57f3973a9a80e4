"""Named tissue materials from Kato's thesis (SPEC §2.1), defined once for the library, CLI and benchmarks.

* :data:`KATO_UNIFORM` — the uniform material of the thesis's face experiments
  (E = 192.4 kPa, ν = 0.495, η = 476.8 Pa s, ρ = 1100 kg/m³); :func:`kato_uniform_material`
  builds it as a :class:`~warpface.fem.TissueMaterial`.
* :data:`KATO_MODELS` — tables 6.4–6.5: Young's modulus and viscosity of the regions
  :data:`KATO_REGIONS` for the heterogeneous models 1 (healthy), 2 (stiffer right cphs, a scar)
  and 3 (softer right cphs). :func:`warpface.fem.regions.kato_material_model` applies them to a mesh.
"""

from __future__ import annotations

from types import MappingProxyType

from .material import TissueMaterial

__all__ = ["KATO_MODELS", "KATO_REGIONS", "KATO_UNIFORM", "kato_uniform_material"]

KATO_UNIFORM = MappingProxyType({"E": 192.4e3, "nu": 0.495, "eta": 476.8, "rho": 1100.0})
"""Kato's uniform tissue: Young's modulus E [Pa], Poisson's ratio nu, viscosity eta [Pa s], density rho [kg/m^3]."""

KATO_REGIONS = ("cheek", "cphs_L", "cphs_R", "cheilion", "cphi", "alare")
"""Region names of Kato's tables 6.4–6.5, in table order."""


def _table(e_kpa, eta):
    return MappingProxyType(
        {
            "E": MappingProxyType({r: 1e3 * v for r, v in zip(KATO_REGIONS, e_kpa, strict=True)}),
            "eta": MappingProxyType(dict(zip(KATO_REGIONS, eta, strict=True))),
        }
    )


KATO_MODELS = MappingProxyType(
    {
        1: _table((162.7, 148.9, 148.9, 116.5, 169.0, 216.9), (430.3, 408.6, 408.6, 362.9, 453.0, 434.3)),
        2: _table((162.7, 148.9, 205.6, 116.5, 169.0, 216.9), (430.3, 408.6, 427.8, 362.9, 453.0, 434.3)),
        3: _table((162.7, 148.9, 92.2, 116.5, 169.0, 216.9), (430.3, 408.6, 389.4, 362.9, 453.0, 434.3)),
    }
)
"""Kato's models (SPEC §2.1): model -> {"E": region -> Young's modulus [Pa], "eta": region -> viscosity [Pa s]}.
ν = 0.495 and ρ = 1100 kg/m³ everywhere (as in :data:`KATO_UNIFORM`)."""


def kato_uniform_material(*, damping: str = "stokes") -> TissueMaterial:
    """Kato's uniform tissue (:data:`KATO_UNIFORM`) as a :class:`~warpface.fem.TissueMaterial`."""
    return TissueMaterial(**KATO_UNIFORM, damping=damping)
