"""Viscoelastic linear-tet FEM of facial tissue (SPEC §2): mesh, material, assembly, Newmark-β.

Imports only Warp, NumPy and SciPy; optional back ends (pytetwild, pxr, tqdm, cholespy) are
imported lazily where they are used.
"""

from .assembly import FORMULATIONS, SystemMatrices, assemble
from .embedding import Embedding, embed_points
from .integrator import ConvergenceError, TissueSimulation
from .material import DAMPING_MODELS, TissueMaterial
from .primitives import box_tet_mesh, shell_tet_mesh
from .proxy import TissueProxy, tissue_proxy
from .regions import KATO_MODELS, KATO_REGIONS, kato_material_model, kato_regions, landmark_regions
from .tetmesh import TetMesh, TetQuality
from .volume import MeshingReport, TissueMeshing, mesh_tissue, tissue_from_surface

__all__ = [
    "ConvergenceError",
    "DAMPING_MODELS",
    "Embedding",
    "FORMULATIONS",
    "KATO_MODELS",
    "KATO_REGIONS",
    "MeshingReport",
    "SystemMatrices",
    "TetMesh",
    "TetQuality",
    "TissueMaterial",
    "TissueMeshing",
    "TissueProxy",
    "TissueSimulation",
    "assemble",
    "box_tet_mesh",
    "embed_points",
    "kato_material_model",
    "kato_regions",
    "landmark_regions",
    "mesh_tissue",
    "shell_tet_mesh",
    "tissue_from_surface",
    "tissue_proxy",
]
