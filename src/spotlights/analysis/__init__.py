"""Ray-density analysis of Spotlights rigs (paper Section 3.3).

* :mod:`.density` - the density of a surfel at distance ``r`` and orientation ``alpha``
  inside the unit sphere, per unit ``N*M``: accurate quadrature of the paper's integral,
  closed forms, the paper's occlusion formula, caps narrower than the paper's hemisphere.
* :mod:`.montecarlo` - a check with real rigs (``spotlights.geometry.rig``) and real ray
  casting (Embree) on small discs, with statistical errors from random rotations.

Uses ``spotlights.geometry``; knows nothing of learning or data. See ``docs/analysis.md``.
"""

from .density import (
    rho,
    rho_at_points,
    rho_closed_form_alpha0,
    rho_closed_form_alpha_half_pi,
    rho_closed_form_r0,
    rho_direction,
    rho_direction_grid,
    rho_grid,
    rho_paper_integral,
    rho_ring,
)

__all__ = [
    "rho",
    "rho_at_points",
    "rho_closed_form_alpha0",
    "rho_closed_form_alpha_half_pi",
    "rho_closed_form_r0",
    "rho_direction",
    "rho_direction_grid",
    "rho_grid",
    "rho_paper_integral",
    "rho_ring",
]
