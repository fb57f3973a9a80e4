"""Viscoelastic linear-tet FEM of facial tissue (SPEC §2): mesh, material, assembly, Newmark-β.

Imports only Warp, NumPy and SciPy; optional back ends (pytetwild, pxr, tqdm, cholespy) are
imported lazily where they are used.
"""

from .assembly import FORMULATIONS, SystemMatrices, assemble
from .integrator import ConvergenceError, TissueSimulation
from .material import DAMPING_MODELS, TissueMaterial
from .primitives import box_tet_mesh, shell_tet_mesh
from .tetmesh import TetMesh, TetQuality

__all__ = [
    "ConvergenceError",
    "DAMPING_MODELS",
    "FORMULATIONS",
    "SystemMatrices",
    "TetMesh",
    "TetQuality",
    "TissueMaterial",
    "TissueSimulation",
    "assemble",
    "box_tet_mesh",
    "shell_tet_mesh",
]
