"""Viscoelastic linear-tet FEM of facial tissue (SPEC §2): mesh, material, assembly, Newmark-β.

Model layer: imports Warp, NumPy, SciPy and warpface's geometry layer (``warpface.geometry``,
``warpface.landmarks``), never USD, tracking, metrics or assets; optional back ends (pytetwild,
PyVista, tqdm) are imported lazily where they are used. Tissue meshes and materials are read and
written on USD stages by :mod:`warpface.usd.tissue_io`.

Stepping follows Newton's split: the model (a :class:`TetMesh` and its :class:`TissueMaterial`, assembled),
a :class:`TissueState`, a :class:`TissueControl` and a solver whose ``solver.step(state_in, state_out, control,
dt)`` advances one state to the next — :class:`~warpface.fem.solver_direct.DirectSolver`,
:class:`~warpface.fem.solver_cg.CGSolver`, and for batched states :class:`~warpface.fem.solver_batch.BatchedCGSolver`
or :class:`~warpface.fem.solver_direct.BatchedDirectSolver`; each has ``reset(state)``, the CG ones take a
:class:`CGOptions`. :class:`TissueSimulation` (and :class:`TissueBatch` for B models) is the convenience wrapper:
it owns the state, control and ``solver``, with one ``step`` and one ``run``.
"""

from ..errors import ConvergenceError
from .assembly import FORMULATIONS, SystemMatrices, assemble
from .batch import TissueBatch
from .embedding import Embedding, embed_points
from .integrator import TissueSimulation
from .material import DAMPING_MODELS, MATERIAL_RANGES, TissueMaterial
from .options import CGOptions
from .presets import KATO_MODELS, KATO_REGIONS, KATO_UNIFORM, kato_uniform_material
from .primitives import box_tet_mesh, shell_tet_mesh
from .proxy import TissueProxy, tissue_proxy
from .regions import kato_material_model, kato_regions, landmark_regions
from .state import TissueControl, TissueState
from .tetmesh import TetMesh, TetQuality
from .volume import MeshingReport, TissueMeshing, mesh_tissue, tissue_from_surface

__all__ = [
    "CGOptions",
    "ConvergenceError",
    "DAMPING_MODELS",
    "Embedding",
    "FORMULATIONS",
    "KATO_MODELS",
    "KATO_REGIONS",
    "KATO_UNIFORM",
    "MATERIAL_RANGES",
    "MeshingReport",
    "SystemMatrices",
    "TetMesh",
    "TetQuality",
    "TissueMaterial",
    "TissueControl",
    "TissueMeshing",
    "TissueProxy",
    "TissueBatch",
    "TissueSimulation",
    "TissueState",
    "assemble",
    "box_tet_mesh",
    "embed_points",
    "kato_material_model",
    "kato_regions",
    "kato_uniform_material",
    "landmark_regions",
    "mesh_tissue",
    "shell_tet_mesh",
    "tissue_from_surface",
    "tissue_proxy",
]
