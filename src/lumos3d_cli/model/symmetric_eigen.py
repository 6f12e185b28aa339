"""Batched eigendecomposition of symmetric 3x3 matrices (Gaussian covariances), on any device.

`torch.linalg.eigh` fails on CUDA for large float64 batches of 3x3 matrices (cuSOLVER raises
CUSOLVER_STATUS_INTERNAL_ERROR on the ~1e5 covariances of a real scene), and on the CPU LAPACK's
per-matrix overhead makes it slower than this at that size. This is cyclic Jacobi on the six
distinct entries held as separate [B] tensors: element-wise torch only, so every device and
batch size runs the same arithmetic.

Why Jacobi and not the closed form (trigonometric eigenvalues, cross-product eigenvectors): the
closed form loses about half the digits near repeated eigenvalues (acos at +-1; isotropic and
flat Gaussians are common here), while Jacobi is backward stable: eigenvalues within a few eps of
the largest entry, eigenvectors orthonormal to a few eps, repeated eigenvalues included. Each
rotation zeroes one off-diagonal entry exactly and convergence is quadratic, so four sweeps of
three rotations reach rounding level in float32 and float64.
"""

from __future__ import annotations

import torch

_MAX_SWEEPS = 10  # a cap, not a cost: 4 sweeps converge on random, clustered and rank-deficient matrices
_PAIRS = ((0, 1, 2), (0, 2, 1), (1, 2, 0))  # (p, q, r): rotate in the p-q plane, r the third axis


def _key(i: int, j: int) -> tuple[int, int]:
    return (i, j) if i < j else (j, i)


def symmetric_eigen_3x3(matrices: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Symmetric [..., 3, 3] -> (eigenvalues [..., 3] ascending, eigenvectors [..., 3, 3]).

    Like `torch.linalg.eigh`: matrices = V diag(eigenvalues) V^T with the eigenvectors as the
    columns of V. Unlike it, V is always a rotation (orthonormal and right-handed, det +1), so a
    caller can turn it into a quaternion as it is; the symmetric part (A + A^T) / 2 is used, not
    one triangle; and a matrix with any NaN or Inf entry gets all-NaN eigenvalues and
    eigenvectors (the others in the batch are unaffected), never finite garbage.

    Each matrix is divided by a power of two near its largest absolute entry first, so entries
    anywhere in the floating-point range (1e-30 and 1e30 in float32 too) neither underflow nor
    overflow.
    float32 and float64 are computed in their own precision, float16 / bfloat16 in float32 and
    returned in the input dtype. Meant for inference: gradients through the iterations exist but
    are as unstable as any eigendecomposition's at repeated eigenvalues.
    """
    if matrices.dim() < 2 or matrices.shape[-2:] != (3, 3):
        raise ValueError(f"symmetric_eigen_3x3 needs [..., 3, 3] matrices, got shape {tuple(matrices.shape)}")
    if not matrices.is_floating_point():
        raise TypeError(f"symmetric_eigen_3x3 needs a floating-point tensor, got {matrices.dtype}")
    batch_shape, dtype = matrices.shape[:-2], matrices.dtype
    work = matrices.reshape(-1, 3, 3)
    if dtype not in (torch.float32, torch.float64):
        work = work.float()  # too few digits for the rotations to converge to anything useful
    eps, tiny = torch.finfo(work.dtype).eps, torch.finfo(work.dtype).tiny

    finite = torch.isfinite(work).all(dim=-1).all(dim=-1)
    # A power of two near the largest entry: dividing by it and multiplying back is exact, so a
    # diagonal matrix gives its diagonal bit for bit. log2 / exp2 rather than frexp, which not
    # every backend has; log2 rounding up just below a power of two only leaves the largest
    # normalised entry just under 1 instead of in [1, 2).
    largest = work.abs().amax(dim=(-2, -1))
    scale = torch.exp2(torch.floor(torch.log2(largest)))
    scale = torch.where(largest > 0, scale, torch.ones_like(scale))  # zero matrix: already diagonal
    work = work / scale[:, None, None]
    diagonal = [work[:, i, i] for i in range(3)]
    off = {(i, j): (work[:, i, j] + work[:, j, i]) / 2 for i, j in ((0, 1), (0, 2), (1, 2))}
    one, zero = torch.ones_like(diagonal[0]), torch.zeros_like(diagonal[0])
    # The columns of V as [3, B] tensors: a rotation updates two whole columns in four ops (the
    # CPU cost here is the number of element-wise ops, not their size).
    identity = torch.eye(3, dtype=work.dtype, device=work.device)
    columns = [identity[:, k, None].expand(3, len(one)) for k in range(3)]

    for _ in range(_MAX_SWEEPS):
        for p, q, r in _PAIRS:
            apq = off[(p, q)]
            # The smaller of the two rotations that zero a_pq (Golub & Van Loan's symmetric
            # Schur), t = tan(angle) = sign(tau) / (|tau| + sqrt(1 + tau^2)) with
            # tau = (a_qq - a_pp) / (2 a_pq), multiplied through by 2 |a_pq| so that a_pq = 0
            # needs no division by it. `tiny` keeps 0 / 0 (a_pq = 0 and a_pp = a_qq) at t = 0; it
            # can only shorten rotations of entries below it, some 1e-300 of the largest (1 to 2).
            difference = diagonal[q] - diagonal[p]
            twice = 2 * apq
            t = twice / torch.copysign(difference.abs() + torch.hypot(difference, twice) + tiny, difference)
            c = torch.rsqrt(torch.addcmul(one, t, t))
            s = t * c
            diagonal[p] = torch.addcmul(diagonal[p], t, apq, value=-1)
            diagonal[q] = torch.addcmul(diagonal[q], t, apq)
            off[(p, q)] = zero
            arp, arq = off[_key(r, p)], off[_key(r, q)]
            off[_key(r, p)] = torch.addcmul(c * arp, s, arq, value=-1)
            off[_key(r, q)] = torch.addcmul(c * arq, s, arp)
            vp, vq = columns[p], columns[q]
            columns[p] = torch.addcmul(c * vp, s, vq, value=-1)
            columns[q] = torch.addcmul(c * vq, s, vp)
        # Off-diagonals below eps of the normalised matrix (largest entry about 1 to 2) move the
        # eigenvalues by less than the input's own rounding. One host sync a sweep; NaN rows
        # compare False and so never keep the loop going.
        largest_off = torch.maximum(torch.maximum(off[(0, 1)].abs(), off[(0, 2)].abs()), off[(1, 2)].abs())
        if not bool((largest_off > eps).any()):
            break

    # Sort ascending with a three-comparator network. Swapping two columns flips det(V), so one
    # of the pair is negated as well: V stays a product of rotations, det +1, with no det to test.
    for i, j in ((0, 1), (1, 2), (0, 1)):
        swap = diagonal[i] > diagonal[j]
        low, high = torch.where(swap, diagonal[j], diagonal[i]), torch.where(swap, diagonal[i], diagonal[j])
        diagonal[i], diagonal[j] = low, high
        columns[i], columns[j] = torch.where(swap, columns[j], columns[i]), torch.where(swap, -columns[i], columns[j])

    eigenvalues = torch.stack(diagonal, dim=-1) * scale[:, None]
    eigenvectors = torch.stack(columns, dim=-1).permute(1, 0, 2)  # [3 rows, B, 3 columns] -> [B, 3, 3]
    nan = torch.full((), float("nan"), dtype=eigenvalues.dtype, device=eigenvalues.device)
    eigenvalues = torch.where(finite[:, None], eigenvalues, nan)
    eigenvectors = torch.where(finite[:, None, None], eigenvectors, nan)
    return eigenvalues.reshape(batch_shape + (3,)).to(dtype), eigenvectors.reshape(batch_shape + (3, 3)).to(dtype)
