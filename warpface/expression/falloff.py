"""Zone falloffs of the Waters muscles (float64 Warp functions): the §1.1 forms and C¹ ones (SPEC §6.3).

``smooth = 0`` selects SPEC §1.1 exactly; ``smooth = 1`` the forms of docs/RIG.md §1, which reach zero
with zero slope at every zone edge (angle Ω, radius Rf, the attachment, the sphincter rim), so the
skin shows no crease where a muscle's influence ends:

- angular   ``A = cos²(μ/Ω · π/2)``
- radial    ``R = sin²(D/Rs · π/2)`` for ``D < Rs``, ``cos²((D − Rs)/(Rf − Rs) · π/2)`` for ``Rs ≤ D ≤ Rf``
- sphincter ``f = (1 − ρ²)²`` with ``ρ² = x²/lx² + y²/ly²``, zero outside the rim.
"""

import math

import warp as wp

__all__ = ["linear_angular_factor", "linear_radial_factor", "sphincter_factor", "sphincter_ring_factor"]

_HALF_PI = wp.constant(wp.float64(math.pi / 2.0))


@wp.func
def linear_angular_factor(mu: wp.float64, zone: wp.float64, smooth: int):
    """Angular factor at angle ``mu`` ∈ [0, zone] from the muscle axis (``zone`` = Ω) [rad]."""
    c = wp.cos(mu / zone * _HALF_PI)
    if smooth != 0:
        return c * c
    return c


@wp.func
def linear_radial_factor(distance: wp.float64, start: wp.float64, finish: wp.float64, smooth: int):
    """Radial factor at ``distance`` ∈ (0, finish] from the attachment, rising to 1 at ``start`` (Rs)."""
    if distance < start:
        if smooth != 0:
            s = wp.sin(distance / start * _HALF_PI)
            return s * s
        return wp.cos((wp.float64(1.0) - distance / start) * _HALF_PI)
    c = wp.cos((distance - start) / (finish - start) * _HALF_PI)
    if smooth != 0:
        return c * c
    return c


@wp.func
def sphincter_factor(rho_squared: wp.float64, smooth: int):
    """Sphincter weight at elliptic radius² ``rho_squared`` (1 at the centre, 0 on and beyond the rim)."""
    zero = wp.float64(0.0)
    if rho_squared >= wp.float64(1.0):
        return zero
    if smooth != 0:
        f = wp.float64(1.0) - rho_squared
        return f * f
    return wp.float64(1.0) - wp.sqrt(rho_squared)


@wp.func
def sphincter_ring_factor(rho_squared: wp.float64, ring: wp.float64):
    """Ring factor of a sphincter with an inner part it does not move: ``sin²(ρ/ring · π/2)`` inside ``ρ < ring``, else 1."""
    if ring <= wp.float64(0.0):
        return wp.float64(1.0)
    rho = wp.sqrt(rho_squared)
    if rho >= ring:
        return wp.float64(1.0)
    s = wp.sin(rho / ring * _HALF_PI)
    return s * s
