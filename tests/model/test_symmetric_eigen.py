"""symmetric_eigen_3x3 against torch.linalg.eigh in float64 on the CPU (the oracle), and
covering_shapes against its former eigh-based computation."""

import pytest
import torch

from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.model.symmetric_eigen import symmetric_eigen_3x3
from lumos3d_cli.model.voxelize import covering_shapes, voxelize
from lumos3d_cli.rotations import quaternion_to_matrix

DTYPES = (torch.float64, torch.float32)


def _rotations(n: int, generator: torch.Generator) -> torch.Tensor:
    return quaternion_to_matrix(torch.randn(n, 4, generator=generator, dtype=torch.float64))


def _from_spectrum(rotations: torch.Tensor, eigenvalues: torch.Tensor) -> torch.Tensor:
    """R diag(lambda) R^T, symmetrised (the rounding of the product is not)."""
    matrices = (rotations * eigenvalues[:, None, :]) @ rotations.transpose(1, 2)
    return (matrices + matrices.transpose(1, 2)) / 2


def _check_against_eigh(matrices: torch.Tensor, tolerance: float = 30.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Eigenvalues, reconstruction, orthonormality and det +1 within `tolerance` eps of the
    matrix's norm, against float64 eigh of the same (dtype-rounded) matrices on the CPU."""
    eps = torch.finfo(matrices.dtype).eps
    eigenvalues, vectors = symmetric_eigen_3x3(matrices)
    assert eigenvalues.dtype == vectors.dtype == matrices.dtype
    assert eigenvalues.shape == matrices.shape[:-1] and vectors.shape == matrices.shape
    exact = matrices.double().cpu()
    eigenvalues, vectors = eigenvalues.double().cpu(), vectors.double().cpu()
    norm = exact.flatten(-2).norm(dim=-1)
    expected = torch.linalg.eigh(exact).eigenvalues
    assert ((eigenvalues - expected).abs().amax(-1) <= tolerance * eps * norm).all()
    assert (eigenvalues[..., :-1] <= eigenvalues[..., 1:]).all()
    rebuilt = (vectors * eigenvalues[..., None, :]) @ vectors.transpose(-1, -2)
    assert ((rebuilt - exact).flatten(-2).norm(dim=-1) <= tolerance * eps * norm).all()
    gram = vectors.transpose(-1, -2) @ vectors
    assert (gram - torch.eye(3, dtype=torch.float64)).abs().max() <= tolerance * eps
    assert (torch.linalg.det(vectors) - 1).abs().max() <= tolerance * eps
    return eigenvalues, vectors


@pytest.mark.parametrize("dtype", DTYPES)
def test_random_spd_and_indefinite_matrices(dtype):
    g = torch.Generator().manual_seed(0)
    factors = torch.randn(2000, 3, 3, generator=g, dtype=torch.float64)
    _check_against_eigh((factors @ factors.transpose(1, 2)).to(dtype))
    _check_against_eigh((factors + factors.transpose(1, 2)).to(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_eigenvectors_match_eigh_where_the_eigenvalues_are_apart(dtype):
    g = torch.Generator().manual_seed(1)
    factors = torch.randn(2000, 3, 3, generator=g, dtype=torch.float64)
    matrices = (factors @ factors.transpose(1, 2)).to(dtype)
    _, vectors = _check_against_eigh(matrices)
    expected_values, expected = torch.linalg.eigh(matrices.double())
    norm = matrices.double().flatten(-2).norm(dim=-1)
    gap = torch.diff(expected_values, dim=-1).amin(-1) / norm
    apart = gap > 1e-2
    assert apart.sum() > 1000
    # Columns agree up to sign, to within a few eps / gap (the eigenvectors' condition number).
    signs = torch.where((vectors * expected).sum(dim=-2) < 0, -1.0, 1.0).double()
    error = (vectors * signs[:, None, :] - expected).norm(dim=-2).amax(-1)
    assert (error[apart] <= 10 * torch.finfo(dtype).eps / gap[apart]).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_rotated_scales_from_1e_minus_6_to_1e6(dtype):
    # Standard deviations 1e-6..1e6, so variances 1e-12..1e12 in one matrix: the small ones are
    # only determined to eps times the largest, which is what eigh gives too.
    g = torch.Generator().manual_seed(2)
    scales = 10 ** (torch.rand(3000, 3, generator=g, dtype=torch.float64) * 12 - 6)
    _check_against_eigh(_from_spectrum(_rotations(3000, g), scales**2).to(dtype))


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("factor", [1e-30, 1e-12, 1e12, 1e30])
def test_overall_scale_is_divided_out(dtype, factor):
    # Entries of 1e-30 square to below float32's range and 1e30 to above it: without the
    # normalisation the rotations would underflow to zero or overflow to Inf.
    g = torch.Generator().manual_seed(3)
    unit = _from_spectrum(_rotations(500, g), torch.rand(500, 3, generator=g, dtype=torch.float64) + 0.01)
    eigenvalues, _ = _check_against_eigh((unit * factor).to(dtype))
    unit_values, _ = symmetric_eigen_3x3(unit.to(dtype))
    # The two roundings to dtype differ, so agreement is to eps of the matrix's norm.
    norm = unit.flatten(-2).norm(dim=-1)[:, None]
    assert ((eigenvalues / factor - unit_values.double()).abs() <= 30 * torch.finfo(dtype).eps * norm).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_exactly_repeated_eigenvalues(dtype):
    g = torch.Generator().manual_seed(4)
    n = 1000
    base = torch.rand(n, 1, generator=g, dtype=torch.float64) + 0.1
    other = torch.rand(n, 1, generator=g, dtype=torch.float64) * 3 + 0.1
    spectra = {
        "isotropic": base.expand(n, 3),
        "two equal, third larger": torch.cat([base, base, base + other], 1),
        "two equal, third smaller": torch.cat([base, base + other, base + other], 1),
        "two equal, third 1e-8 apart": torch.cat([base, base, base * (1 + 1e-8)], 1),
    }
    rotations = _rotations(n, g)
    for spectrum in spectra.values():
        _check_against_eigh(_from_spectrum(rotations, spectrum).to(dtype))
    # An exactly isotropic matrix (no rotation rounding) gives exactly its eigenvalue.
    isotropic = torch.eye(3, dtype=dtype) * 2.5
    eigenvalues, vectors = symmetric_eigen_3x3(isotropic)
    assert eigenvalues.tolist() == [2.5, 2.5, 2.5] and torch.equal(vectors, torch.eye(3, dtype=dtype))


@pytest.mark.parametrize("dtype", DTYPES)
def test_diagonal_matrices_give_the_sorted_diagonal_exactly(dtype):
    g = torch.Generator().manual_seed(5)
    diagonals = torch.randn(500, 3, generator=g, dtype=dtype) * 10.0 ** torch.randint(-6, 7, (500, 3), generator=g)
    eigenvalues, vectors = symmetric_eigen_3x3(torch.diag_embed(diagonals))
    assert torch.equal(eigenvalues, diagonals.sort(-1).values)
    assert torch.equal(vectors.abs().sum(-1), torch.ones(500, 3, dtype=dtype))  # a signed permutation
    assert (torch.linalg.det(vectors.double()) == 1).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_rank_deficient_and_zero_matrices(dtype):
    g = torch.Generator().manual_seed(6)
    n = 1000
    rotations = _rotations(n, g)
    sizes = torch.rand(n, 3, generator=g, dtype=torch.float64) + 0.1
    flat = sizes * torch.tensor([0.0, 1.0, 1.0], dtype=torch.float64)  # a disc's covariance
    needle = sizes * torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    for spectrum in (flat, needle, torch.zeros(n, 3, dtype=torch.float64)):
        _check_against_eigh(_from_spectrum(rotations, spectrum).to(dtype))
    eigenvalues, vectors = symmetric_eigen_3x3(torch.zeros(3, 3, dtype=dtype))
    assert torch.equal(eigenvalues, torch.zeros(3, dtype=dtype)) and torch.equal(vectors, torch.eye(3, dtype=dtype))


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_matrices_give_nan_and_leave_the_others_alone(bad):
    g = torch.Generator().manual_seed(7)
    factors = torch.randn(4, 3, 3, generator=g, dtype=torch.float64)
    matrices = factors @ factors.transpose(1, 2)
    clean_values, clean_vectors = symmetric_eigen_3x3(matrices)
    matrices[1, 0, 2] = bad  # the upper triangle only: eigh would read the lower one and miss it
    matrices[3, 2, 2] = bad
    eigenvalues, vectors = symmetric_eigen_3x3(matrices)
    for row in (1, 3):
        assert eigenvalues[row].isnan().all() and vectors[row].isnan().all()
    for row in (0, 2):
        assert torch.equal(eigenvalues[row], clean_values[row]) and torch.equal(vectors[row], clean_vectors[row])


def test_batch_shapes_and_dtypes():
    g = torch.Generator().manual_seed(8)
    factors = torch.randn(2, 5, 3, 3, generator=g)
    matrices = factors @ factors.transpose(-1, -2)
    eigenvalues, vectors = symmetric_eigen_3x3(matrices)
    assert eigenvalues.shape == (2, 5, 3) and vectors.shape == (2, 5, 3, 3)
    single_values, single_vectors = symmetric_eigen_3x3(matrices[1, 3])
    assert torch.equal(single_values, eigenvalues[1, 3]) and torch.equal(single_vectors, vectors[1, 3])
    empty_values, empty_vectors = symmetric_eigen_3x3(torch.zeros(0, 3, 3))
    assert empty_values.shape == (0, 3) and empty_vectors.shape == (0, 3, 3)
    half_values, _ = symmetric_eigen_3x3(matrices.to(torch.bfloat16))
    assert half_values.dtype == torch.bfloat16
    expected = torch.linalg.eigh(matrices.to(torch.bfloat16).float()).eigenvalues
    assert ((half_values.float() - expected).abs() <= 1e-2 * expected.abs().amax(-1, keepdim=True)).all()
    with pytest.raises(ValueError, match=r"\[\.\.\., 3, 3\]"):
        symmetric_eigen_3x3(torch.zeros(4, 2, 2))
    with pytest.raises(TypeError, match="floating-point"):
        symmetric_eigen_3x3(torch.zeros(4, 3, 3, dtype=torch.int64))


def _covariances(gaussians: Gaussians) -> torch.Tensor:
    rotations = quaternion_to_matrix(gaussians.quats.double())
    return (rotations * gaussians.scales.double()[:, None, :] ** 2) @ rotations.transpose(1, 2)


def _covering_shapes_with_eigh(voxels: Gaussians, members: Gaussians, fusion, min_scale: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The former covering_shapes (torch.linalg.eigh on the CPU) -> (scales [M, 3], covariances
    [M, 3, 3]); eigenvector signs are arbitrary, so the covariances are what to compare."""
    shared = fusion.counts > 1
    in_shared = shared[fusion.inverse]
    index = fusion.inverse[in_shared]
    axes = quaternion_to_matrix(members.quats[in_shared].double()) * members.scales[in_shared].double()[:, None, :]
    offsets = (members.means[in_shared] - fusion.points[index]).double()
    spread = axes @ axes.transpose(1, 2) + offsets[:, :, None] * offsets[:, None, :]
    covariance = torch.zeros(len(fusion), 3, 3, dtype=torch.float64).index_add(
        0, index, spread * fusion.weights[in_shared].double()[:, None, None]
    )[shared]
    variances, vectors = torch.linalg.eigh(covariance)
    scales = voxels.scales.double().clone()
    scales[shared] = variances.clamp_min(0).sqrt().clamp_min(min_scale)
    covariances = _covariances(voxels)
    covariances[shared] = (vectors * scales[shared][:, None, :] ** 2) @ vectors.transpose(1, 2)
    return scales, covariances


def _pixel_like_members(n: int, seed: int) -> tuple[Gaussians, torch.Tensor]:
    """Gaussians like a few views' pixels: clustered means, flat and needle shapes among them,
    some exactly isotropic and coincident (members of a voxel that match exactly)."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * 0.5
    quats = torch.randn(n, 4, generator=g)
    scales = torch.exp(torch.randn(n, 3, generator=g) - 4)
    scales[: n // 8, 0] = 1e-7  # flat
    scales[n // 8 : n // 4, :2] = 1e-7  # needles
    scales[n // 4 : n // 3] = 0.02  # isotropic
    means[n // 4 : n // 3] = means[n // 4]  # and coincident: one voxel of equal isotropic members
    confidence = torch.randn(n, generator=g)
    return Gaussians(means, quats, scales, torch.ones(n), torch.zeros(n, 1, 3)), confidence


@pytest.mark.parametrize("seed", [0, 1])
def test_covering_shapes_match_the_former_eigh_computation(seed):
    members, confidence = _pixel_like_members(4000, seed)
    fusion = voxelize(members.means, torch.zeros(len(members), 1), confidence, 0.15)
    assert (fusion.counts > 1).sum() > 100
    voxels = Gaussians(fusion.points, torch.randn(len(fusion), 4), torch.full((len(fusion), 3), 0.01),
                       torch.ones(len(fusion)), torch.zeros(len(fusion), 1, 3))
    min_scale = 1e-5
    covered = covering_shapes(voxels, members, fusion, min_scale)
    expected_scales, expected_covariances = _covering_shapes_with_eigh(voxels, members, fusion, min_scale)
    # Float32 outputs: scales agree to float32 rounding, covariances to float32 rounding of the
    # largest variance (the quaternion is rounded to float32 too).
    torch.testing.assert_close(covered.scales.double(), expected_scales, rtol=1e-6, atol=0)
    largest = expected_covariances.flatten(1).abs().amax(1)[:, None, None]
    assert ((_covariances(covered) - expected_covariances).abs() <= 1e-6 * largest).all()
    single = fusion.counts == 1
    assert (covered.quats[~single, 0] >= 0).all() and torch.isfinite(covered.quats).all()
    assert torch.equal(covered.quats[single], voxels.quats[single]) and torch.equal(covered.scales[single], voxels.scales[single])


def test_covering_shapes_propagate_a_non_finite_member_as_nan():
    # The model's output check (`_require_finite_output`) is what reports it; covering_shapes must
    # not turn it into a finite shape on the way.
    members, confidence = _pixel_like_members(400, 2)
    members.scales[5] = float("nan")
    fusion = voxelize(members.means, torch.zeros(len(members), 1), confidence, 0.5)
    assert fusion.counts[fusion.inverse[5]] > 1
    voxels = Gaussians(fusion.points, torch.randn(len(fusion), 4), torch.full((len(fusion), 3), 0.01),
                       torch.ones(len(fusion)), torch.zeros(len(fusion), 1, 3))
    covered = covering_shapes(voxels, members, fusion, 1e-5)
    bad = fusion.inverse[5]
    assert covered.scales[bad].isnan().all() and covered.quats[bad].isnan().all()
    others = torch.arange(len(fusion)) != bad
    assert torch.isfinite(covered.scales[others]).all() and torch.isfinite(covered.quats[others]).all()


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("dtype", DTYPES)
def test_on_cuda_a_large_batch_matches_cpu_eigh(dtype):
    # The batch size at which cuSOLVER's eigh failed with CUSOLVER_STATUS_INTERNAL_ERROR.
    g = torch.Generator().manual_seed(9)
    n = 200_000
    scales = 10 ** (torch.rand(n, 3, generator=g, dtype=torch.float64) * 6 - 3)
    scales[: n // 4, 1] = scales[: n // 4, 0]  # two equal
    scales[n // 4 : n // 2, 0] = 0  # flat
    _check_against_eigh(_from_spectrum(_rotations(n, g), scales**2).to(dtype).cuda())
