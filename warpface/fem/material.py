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

import numpy as np

__all__ = ["TissueMaterial", "DAMPING_MODELS"]

DAMPING_MODELS = ("stokes", "thesis")

_FIELDS = ("E", "nu", "eta", "rho")


def _as_field(name: str, value) -> np.ndarray | float:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        return float(arr)
    if arr.ndim != 1:
        raise ValueError(f"TissueMaterial {name} must be a scalar or a 1-D per-tet array, got shape {arr.shape}")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


def _check_range(name: str, value, ok, what: str) -> None:
    arr = np.atleast_1d(value)
    bad = np.flatnonzero(~(np.isfinite(arr) & ok(arr)))
    if bad.size:
        where = "" if np.ndim(value) == 0 else f" at tet {bad[0]}"
        raise ValueError(f"TissueMaterial {name}{where} must be {what}, got {arr[bad[0]]!r}")


class TissueMaterial:
    """Isotropic linear viscoelastic material, uniform or per tet.

    Args:
        E: Young's modulus [Pa], > 0. Scalar or shape (M,).
        nu: Poisson's ratio, 0 <= nu < 0.5. Scalar or shape (M,).
        eta: Shear viscosity [Pa s], >= 0. Scalar or shape (M,).
        rho: Density [kg/m^3], > 0. Scalar or shape (M,).
        damping: Viscous law, ``"stokes"`` (isotropic, default) or ``"thesis"`` (the
            thesis's printed, non-isotropic matrix, for reproduction only).

    Raises:
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
        if damping not in DAMPING_MODELS:
            raise ValueError(f"TissueMaterial damping must be one of {DAMPING_MODELS}, got {damping!r}")
        self.damping = damping
        """Viscous law: "stokes" or "thesis"."""

        _check_range("E", self.E, lambda a: a > 0.0, "> 0 [Pa]")
        _check_range("nu", self.nu, lambda a: (a >= 0.0) & (a < 0.5), "in [0, 0.5)")
        _check_range("eta", self.eta, lambda a: a >= 0.0, ">= 0 [Pa s]")
        _check_range("rho", self.rho, lambda a: a > 0.0, "> 0 [kg/m^3]")
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
        fields = base.per_tet(tet_count)
        for region, values in overrides.items():
            if region not in regions:
                raise ValueError(f"TissueMaterial region {region!r} is not defined; known: {sorted(regions)}")
            unknown = set(values) - set(_FIELDS)
            if unknown:
                raise ValueError(f"TissueMaterial region {region!r} sets unknown fields {sorted(unknown)}")
            sel = np.asarray(regions[region])
            if sel.dtype == bool:
                if sel.shape != (tet_count,):
                    raise ValueError(
                        f"TissueMaterial region {region!r} mask has shape {sel.shape}, expected ({tet_count},)"
                    )
                index = np.flatnonzero(sel)
            else:
                index = sel.astype(np.int64).ravel()
                if index.size and (index.min() < 0 or index.max() >= tet_count):
                    raise ValueError(
                        f"TissueMaterial region {region!r} has tet index out of range [0, {tet_count})"
                    )
            for name, value in values.items():
                fields[name][index] = float(value)
        return cls(**fields, damping=base.damping)

    def __repr__(self) -> str:
        def fmt(v):
            return f"{v:.4g}" if np.ndim(v) == 0 else f"[{np.min(v):.4g}..{np.max(v):.4g}]"

        return (
            f"TissueMaterial(E={fmt(self.E)} Pa, nu={fmt(self.nu)}, eta={fmt(self.eta)} Pa s, "
            f"rho={fmt(self.rho)} kg/m^3, damping={self.damping!r})"
        )
