"""Device-resident results: evaluate(..., out=...) writes the same bits as the NumPy path,
into Warp arrays and (zero-copy, DLPack) foreign arrays, with host or device controls."""

import numpy as np
import pytest
import warp as wp
from helpers import small_face_rig

DEVICE = "cpu"


@pytest.fixture(scope="module")
def model():
    return small_face_rig().model(device=DEVICE)


def random_controls(model, rng, frames):
    contractions = rng.uniform(0.0, 0.02, (frames, len(model.muscles)))
    contractions[:, 2] = rng.uniform(0.0, 0.6, frames)  # the sphincter, dimensionless
    depths = rng.uniform(0.0, 0.003, (frames, len(model.wrinkles)))
    return contractions, depths


def test_single_frame_into_warp_array_is_bit_identical(model, rng):
    contractions, depths = random_controls(model, rng, 1)
    expected = model.evaluate(contractions[0], wrinkle_depths=depths[0])
    vec = wp.empty(model.mesh.vertex_count, dtype=wp.vec3, device=DEVICE)
    assert model.evaluate(contractions[0], out=vec, wrinkle_depths=depths[0]) is vec
    np.testing.assert_array_equal(vec.numpy(), expected)
    flat = wp.empty((model.mesh.vertex_count, 3), dtype=wp.float32, device=DEVICE)
    model.evaluate(dict(zip(model.muscle_names, contractions[0])), out=flat, wrinkle_depths=depths[0])
    np.testing.assert_array_equal(flat.numpy(), expected)


def test_device_controls_equal_host_controls(model, rng):
    contractions, depths = random_controls(model, rng, 1)
    expected = model.evaluate(contractions[0], wrinkle_depths=depths[0])
    out = wp.empty(model.mesh.vertex_count, dtype=wp.vec3, device=DEVICE)
    model.evaluate(
        wp.array(contractions[0].astype(np.float32), device=DEVICE),
        out=out,
        wrinkle_depths=wp.array(depths[0].astype(np.float32), device=DEVICE),
    )
    np.testing.assert_array_equal(out.numpy(), expected)
    # device contractions with the wrinkles' own default depths
    model.evaluate(wp.array(contractions[0].astype(np.float32), device=DEVICE), out=out)
    np.testing.assert_array_equal(out.numpy(), model.evaluate(contractions[0]))


@pytest.mark.parametrize("frames_per_launch", [None, 2, 5])
def test_batch_into_is_bit_identical(model, rng, frames_per_launch):
    contractions, depths = random_controls(model, rng, 7)
    expected = model.evaluate(contractions, wrinkle_depths=depths, frames_per_launch=frames_per_launch)
    out = wp.empty((7, model.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
    model.evaluate(contractions, out=out, wrinkle_depths=depths, frames_per_launch=frames_per_launch)
    np.testing.assert_array_equal(out.numpy(), expected)
    flat = wp.empty((7, model.mesh.vertex_count, 3), dtype=wp.float32, device=DEVICE)
    model.evaluate(
        wp.array(contractions.astype(np.float32), device=DEVICE),
        out=flat,
        wrinkle_depths=wp.array(depths.astype(np.float32), device=DEVICE),
        frames_per_launch=frames_per_launch,
    )
    np.testing.assert_array_equal(flat.numpy(), expected)


def test_dlpack_output_is_written_in_place(model, rng):
    """A foreign array shared through DLPack (here NumPy's own exporter) receives the frame zero-copy."""
    contractions, depths = random_controls(model, rng, 3)
    host = np.zeros((3, model.mesh.vertex_count, 3), dtype=np.float32)

    class Foreign:  # an exporter that is not a NumPy array (as a torch tensor would be)
        def __init__(self, array):
            self.array = array

        def __dlpack__(self, **kwargs):
            return self.array.__dlpack__(**kwargs)

        def __dlpack_device__(self):
            return self.array.__dlpack_device__()

        @property
        def shape(self):
            return self.array.shape

    model.evaluate(contractions, out=Foreign(host), wrinkle_depths=depths)
    np.testing.assert_array_equal(host, model.evaluate(contractions, wrinkle_depths=depths))
    single = np.zeros((model.mesh.vertex_count, 3), dtype=np.float32)
    model.evaluate(contractions[1], out=Foreign(single), wrinkle_depths=depths[1])
    np.testing.assert_array_equal(single, model.evaluate(contractions[1], wrinkle_depths=depths[1]))


@pytest.mark.parametrize(
    "make, error, message",
    [
        (lambda v: wp.empty(v + 1, dtype=wp.vec3, device=DEVICE), ValueError, "out.*shape"),
        (lambda v: wp.empty(v, dtype=wp.vec3d, device=DEVICE), TypeError, "out.*dtype"),
        (lambda v: wp.empty((v, 4), dtype=wp.float32, device=DEVICE), TypeError, "out"),
        (lambda v: np.zeros((v, 3), dtype=np.float64), TypeError, "out.*dtype"),
        (lambda v: "points", TypeError, "out"),
    ],
)
def test_bad_outputs_are_refused(model, make, error, message):
    with pytest.raises(error, match=message):
        model.evaluate(out=make(model.mesh.vertex_count))


def test_bad_device_controls_are_refused(model):
    out = wp.empty(model.mesh.vertex_count, dtype=wp.vec3, device=DEVICE)
    with pytest.raises(ValueError, match="controls.*shape"):
        model.evaluate(wp.zeros(len(model.muscles) + 1, dtype=wp.float32, device=DEVICE), out=out)
    with pytest.raises(TypeError, match="controls.*dtype"):
        model.evaluate(wp.zeros(len(model.muscles), dtype=wp.float64, device=DEVICE), out=out)


# ------------------------------------------------------------------ the benchmark's PyTorch peer
class _ShimTensor(np.ndarray):
    """A NumPy array with torch's in-place ``index_add_`` (all the peer needs beyond free functions)."""

    def index_add_(self, dim, index, values):
        np.add.at(np.moveaxis(self, dim, 0), index, np.moveaxis(np.asarray(values), dim, 0))
        return self


def numpy_torch_shim():
    """The subset of the torch API that ``benchmarks.expression.TorchExpression`` uses, on NumPy
    (float32 kept: NumPy 2 promotes Python scalars weakly, as torch does)."""
    from types import SimpleNamespace

    def tensor(values, dtype, device):
        return np.array(values, dtype=dtype).view(_ShimTensor)

    return SimpleNamespace(
        float32=np.float32,
        int64=np.int64,
        bool=np.bool_,
        as_tensor=tensor,
        zeros=lambda shape, dtype, device: np.zeros(shape, dtype).view(_ShimTensor),
        cross=lambda a, b, dim: np.cross(a, b, axis=dim),
        cat=lambda parts, dim: np.concatenate(parts, axis=dim),
        clamp=lambda x, min: np.maximum(x, np.float32(min)),
        where=np.where,
        exp=np.exp,
        linalg=SimpleNamespace(vector_norm=lambda x, dim, keepdim: np.linalg.norm(x, axis=dim, keepdims=keepdim)),
    )


@pytest.mark.parametrize("use_torch", [False, True], ids=["numpy-shim", "torch-cpu"])
def test_benchmark_torch_peer_computes_the_model(use_torch):
    """The GPU peer's vectorised math (run here through a NumPy shim of its torch calls, or torch on
    the CPU when installed) equals the Warp model on a batch of frames, within float32 rounding."""
    from benchmarks.expression import TORCH_TOLERANCE, NumpyExpression, TorchExpression, benchmark_rig, wavy_grid
    from warpface import ExpressionModel

    torch = pytest.importorskip("torch") if use_torch else numpy_torch_shim()
    mesh = wavy_grid(900)
    muscles, wrinkles, thickness, contractions = benchmark_rig(mesh)
    model = ExpressionModel(mesh, muscles, wrinkles, thickness, device=DEVICE)
    peer = TorchExpression(NumpyExpression(mesh, muscles, wrinkles, thickness, DEVICE), torch, "cpu")
    rng = np.random.default_rng(11)
    frames = contractions * rng.uniform(0.0, 2.0, (3, len(contractions)))
    depths = model.default_depths * rng.uniform(0.0, 2.0, (3, len(model.wrinkles)))
    expected = model.evaluate(frames, wrinkle_depths=depths)
    got = np.asarray(
        peer.frames(
            torch.as_tensor(frames, dtype=torch.float32, device="cpu"),
            torch.as_tensor(depths, dtype=torch.float32, device="cpu"),
        )
    )
    assert got.shape == expected.shape and got.dtype == np.float32
    assert np.abs(expected - mesh.points).max() > 0.01 * mesh.size  # frames that really move
    assert np.abs(got - expected).max() <= TORCH_TOLERANCE * mesh.size
    # each stage matters: dropping the wrinkles (depth 0) must change the result beyond the tolerance
    flat = np.asarray(
        peer.frames(
            torch.as_tensor(frames, dtype=torch.float32, device="cpu"),
            torch.as_tensor(0 * depths, dtype=torch.float32, device="cpu"),
        )
    )
    assert np.abs(flat - expected).max() > 10 * TORCH_TOLERANCE * mesh.size


def test_batch_into_with_progress_and_partial_chunks(model, rng):
    """The chunked path writes each chunk's frames (the last one partial) straight into the output."""
    contractions, depths = random_controls(model, rng, 5)
    expected = model.evaluate(contractions, wrinkle_depths=depths)
    for progress, frames_per_launch in ((True, None), (False, 2), (True, 3)):
        out = wp.zeros((5, model.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
        model.evaluate(
            contractions, out=out, wrinkle_depths=depths, progress=progress, frames_per_launch=frames_per_launch
        )
        np.testing.assert_array_equal(out.numpy(), expected, err_msg=f"progress={progress}, {frames_per_launch}")
    with pytest.raises(TypeError, match="progress"):
        model.evaluate(contractions, out=out, progress=0)
