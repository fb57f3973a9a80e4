"""Viscoelastic tissue materials: uniform, per tet, or per named region.

A :class:`TissueMaterial` holds Young's modulus ``E`` [Pa], Poisson's ratio ``nu``,
shear viscosity ``eta`` [Pa s] and density ``rho`` [kg/m^3], each a scalar or one value
per tet. The elastic law is isotropic linear elasticity (Kato's thesis eq. 3.27); the
viscous law is chosen by ``damping`` (SPEC §2):

* ``"stokes"`` (default): Stokes' hypothesis, zero bulk viscosity, viscous stress
  ``2 eta dev(eps_dot)``. In Voigt form with engineering shear strains the normal block is
  ``(2 eta / 3) [[2, -1, -1], [-1, 2, -1], [-1, -1, 2]]`` and the shear terms are ``eta``.
* ``"thesis"``: the matrix printed in the thesis (eq. 4.26), normal block ``eta / 3``
  times the same pattern, shear terms ``eta``. It is *not* isotropic (its dissipation
  depends on the orientation of the strain); it exists only to reproduce the thesis.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

MAX_TETS = 1 << 27
"""Largest tet count a per-tet material is made for (134 M; a face tissue has tens of thousands)."""

__all__ = ["TissueMaterial", "DAMPING_MODELS", "MATERIAL_RANGES", "MaterialRange"]

DAMPING_MODELS = ("stokes", "thesis")

_FIELDS = ("E", "nu", "eta", "rho")


@dataclass(frozen=True)
class MaterialRange:
    """Closed interval ``[low, high]`` of one material field, in SI units."""

    low: float
    high: float
    unit: str

    def describe(self) -> str:
        """The interval as text, e.g. ``"in [0.001, 1e+12] Pa"``."""
        return f"in [{self.low:g}, {self.high:g}]" + (f" {self.unit}" if self.unit else "")

    def outside(self, values) -> np.ndarray:
        """Indices of the entries of ``values`` (float64, any shape, flattened) not finite or out of range."""
        arr = np.atleast_1d(np.asarray(values, dtype=np.float64)).ravel()
        return np.flatnonzero(~(np.isfinite(arr) & (arr >= self.low) & (arr <= self.high)))


MATERIAL_RANGES = {
    "E": MaterialRange(1.0e-3, 1.0e12, "Pa"),
    "nu": MaterialRange(0.0, 0.4999, ""),
    "eta": MaterialRange(0.0, 1.0e9, "Pa s"),
    "rho": MaterialRange(1.0e-3, 1.0e6, "kg/m^3"),
}
"""Accepted values of each :class:`TissueMaterial` field (also used when reading a tissue from USD).

Soft tissue is ``E`` ~ 1e3..1e6 Pa, ``nu`` ~ 0.45..0.499, ``eta`` ~ 1..1e3 Pa s and ``rho`` ~ 1e3 kg/m^3;
the intervals are wide around that (steel has E = 2e11 Pa) but keep the assembled matrices finite
and factorisable: ``nu`` up to 0.4999 gives a Lamé ratio lambda/mu of 5,000 (nearer to 0.5 the
"linear" formulation locks and the system matrix loses every significant digit; use
``formulation="anp"`` for incompressible tissue)."""


def _as_field(name: str, value) -> np.ndarray | float:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"TissueMaterial {name} must be a number or an array of numbers") from None
    if arr.ndim == 0:
        return float(arr)
    if arr.ndim != 1:
        raise ValueError(f"TissueMaterial {name} must be a scalar or a 1-D per-tet array, got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"TissueMaterial {name} is an empty array; give a scalar or one value per tet")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


def _check_range(name: str, value) -> None:
    bad = MATERIAL_RANGES[name].outside(value)
    if bad.size:
        where = "" if np.ndim(value) == 0 else f" at tet {bad[0]}"
        got = np.atleast_1d(value)[bad[0]]
        raise ValueError(f"TissueMaterial {name}{where} must be {MATERIAL_RANGES[name].describe()}, got {got!r}")


class TissueMaterial:
    """Isotropic linear viscoelastic material, uniform or per tet.

    Args:
        E: Young's modulus [Pa], in [1e-3, 1e12]. Scalar or shape (M,).
        nu: Poisson's ratio, in [0, 0.4999]. Scalar or shape (M,).
        eta: Shear viscosity [Pa s], in [0, 1e9]. Scalar or shape (M,).
        rho: Density [kg/m^3], in [1e-3, 1e6]. Scalar or shape (M,).
        (The intervals are :data:`MATERIAL_RANGES`.)
        damping: Viscous law, ``"stokes"`` (isotropic, default) or ``"thesis"`` (the
            thesis's printed, non-isotropic matrix, for reproduction only).

    Raises:
        TypeError: ``damping`` is not a string.
        ValueError: a value is out of range or not finite (naming the tet for arrays), per-tet
            arrays disagree in length, or ``damping`` is unknown.
    """

    def __init__(self, E, nu, eta, rho, *, damping: str = "stokes"):
        self.E = _as_field("E", E)
        """Young's modulus [Pa], scalar or shape (M,), float64."""
        self.nu = _as_field("nu", nu)
        """Poisson's ratio, scalar or shape (M,), float64."""
        self.eta = _as_field("eta", eta)
        """Shear viscosity [Pa s], scalar or shape (M,), float64."""
        self.rho = _as_field("rho", rho)
        """Density [kg/m^3], scalar or shape (M,), float64."""
        if not isinstance(damping, str):
            raise TypeError(
                f"TissueMaterial damping must be a str, one of {DAMPING_MODELS}, got {type(damping).__name__}"
            )
        if damping not in DAMPING_MODELS:
            raise ValueError(f"TissueMaterial damping must be one of {DAMPING_MODELS}, got {damping!r}")
        self.damping = damping
        """Viscous law: "stokes" or "thesis"."""

        for name in _FIELDS:
            _check_range(name, getattr(self, name))
        lengths = {name: np.size(getattr(self, name)) for name in _FIELDS if np.ndim(getattr(self, name)) == 1}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"TissueMaterial per-tet arrays differ in length: {lengths}")

    # ------------------------------------------------------------------ per tet
    @property
    def tet_count(self) -> int | None:
        """Length of the per-tet arrays, or None for a uniform material."""
        for name in _FIELDS:
            value = getattr(self, name)
            if np.ndim(value) == 1:
                return int(np.size(value))
        return None

    @property
    def is_uniform(self) -> bool:
        """True when every field is a scalar."""
        return self.tet_count is None

    def per_tet(self, tet_count: int) -> dict[str, np.ndarray]:
        """Every field broadcast to one value per tet.

        Returns:
            ``{"E", "nu", "eta", "rho"}`` -> float64 arrays of shape (tet_count,).

        Raises:
            ValueError: per-tet arrays do not have ``tet_count`` entries.
        """
        own = self.tet_count
        if own is not None and own != tet_count:
            raise ValueError(f"TissueMaterial has {own} per-tet values but the mesh has {tet_count} tets")
        return {name: np.broadcast_to(getattr(self, name), (tet_count,)).astype(np.float64) for name in _FIELDS}

    def lame(self, tet_count: int) -> tuple[np.ndarray, np.ndarray]:
        """Lamé parameters ``(lambda, mu)`` [Pa] per tet, each shape (tet_count,), float64."""
        f = self.per_tet(tet_count)
        mu = f["E"] / (2.0 * (1.0 + f["nu"]))
        lam = f["E"] * f["nu"] / ((1.0 + f["nu"]) * (1.0 - 2.0 * f["nu"]))
        return lam, mu

    # ------------------------------------------------------------------ regions
    @classmethod
    def from_regions(
        cls,
        tet_count: int,
        base: TissueMaterial,
        regions: Mapping[str, object],
        overrides: Mapping[str, Mapping[str, float]],
    ) -> TissueMaterial:
        """Per-tet material from a base material and per-region overrides.

        Expresses tables like Kato's 6.4–6.5 (SPEC §2.1) directly: ``base`` gives every tet
        its values, then each region in ``overrides`` (in mapping order, so a later region wins
        where regions overlap) replaces the named fields on its tets.

        Args:
            tet_count: Number of tets M of the mesh.
            base: Material for tets in no overridden region (uniform or per tet).
            regions: Region name -> tet indices (any integer array-like) or a boolean mask of
                shape (M,).
            overrides: Region name -> ``{"E": ..., "nu": ..., "eta": ..., "rho": ...}`` (any
                subset of the fields, scalars).

        Raises:
            ValueError: an override names an unknown region or field, tet indices are out of
                range, or a resulting value is out of range.
        """
        if not isinstance(base, TissueMaterial):
            raise TypeError(f"TissueMaterial.from_regions base must be a TissueMaterial, got {type(base).__name__}")
        if (
            isinstance(tet_count, bool)
            or not isinstance(tet_count, (int, np.integer))
            or not 1 <= tet_count <= MAX_TETS
        ):
            raise ValueError(
                f"TissueMaterial.from_regions tet_count must be an integer in [1, {MAX_TETS}], got {tet_count!r}"
            )
        if not isinstance(regions, Mapping) or not isinstance(overrides, Mapping):
            raise TypeError("TissueMaterial.from_regions regions and overrides must be mappings (name -> ...)")
        fields = base.per_tet(int(tet_count))
        for region, values in overrides.items():
            if not isinstance(values, Mapping):
                raise TypeError(f"TissueMaterial region {region!r} override must be a mapping of field -> value")
            if region not in regions:
                raise ValueError(f"TissueMaterial region {region!r} is not defined; known: {sorted(regions)}")
            unknown = set(values) - set(_FIELDS)
            if unknown:
                raise ValueError(f"TissueMaterial region {region!r} sets unknown fields {sorted(unknown)}")
            sel = np.asarray(regions[region])
            if sel.dtype != bool and not np.issubdtype(sel.dtype, np.integer) and sel.size:
                raise ValueError(
                    f"TissueMaterial region {region!r} must be tet indices or a boolean mask, got {sel.dtype}"
                )
            if sel.dtype == bool:
                if sel.shape != (tet_count,):
                    raise ValueError(
                        f"TissueMaterial region {region!r} mask has shape {sel.shape}, expected ({tet_count},)"
                    )
                index = np.flatnonzero(sel)
            else:
                index = sel.astype(np.int64).ravel()
                if index.size and (index.min() < 0 or index.max() >= tet_count):
                    raise ValueError(f"TissueMaterial region {region!r} has tet index out of range [0, {tet_count})")
            for name, value in values.items():
                try:
                    fields[name][index] = float(value)
                except (TypeError, ValueError):
                    raise ValueError(
                        f"TissueMaterial region {region!r} {name} must be a number, got {value!r}"
                    ) from None
        return cls(**fields, damping=base.damping)

    def __repr__(self) -> str:
        def fmt(v):
            return f"{v:.4g}" if np.ndim(v) == 0 else f"[{np.min(v):.4g}..{np.max(v):.4g}]"

        return (
            f"TissueMaterial(E={fmt(self.E)} Pa, nu={fmt(self.nu)}, eta={fmt(self.eta)} Pa s, "
            f"rho={fmt(self.rho)} kg/m^3, damping={self.damping!r})"
        )
