"""Surface gradient -> heightmap: least-squares (Poisson) integration with a DCT solver.

The standard GelSight reconstruction step (Johnson & Adelson 2009; Frankot & Chellappa 1988 in
its Neumann-boundary cosine form). Pure JAX, differentiable.

The 2-D cosine transforms of images up to 320 px a side (GelSlim's full 240 x 320 and less) are
products with the (H, H) and (W, W) DCT matrices, ``O(HW (H + W))``: 6 kernels where
``jax.scipy.fft.dctn``/``idctn`` launch 41 (complex FFTs, reorderings), 1.6x faster at
120 x 160 px, 1.1x at 240 x 320 on 2 CPU cores (issue 17). Larger images use the FFTs
(``O(HW log HW)``), faster from about 300 x 400 px. Both give the transform to float32
round-off.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
from jax.scipy.fft import dctn, idctn
from jaxtyping import Array, Float

from tactojax.shape._quantile import quantile as exact_quantile


def integrate_gradient(
    slope: Float[Array, "H W 2"], mm_per_px: float
) -> Float[Array, "H W"]:
    """The heightmap whose finite differences best match a slope field (zero mean).

    Solves ``min_h |D_x h - s_x|^2 + |D_y h - s_y|^2`` exactly, where ``D_x``, ``D_y`` are
    forward differences between neighbouring pixels and ``s`` is the slope averaged onto the
    half-pixel between them. The normal equations are a Poisson equation with Neumann
    boundaries, diagonal in the type-II DCT basis. The solution is defined up to a constant;
    it is returned with zero mean (see :func:`zero_background` to anchor it).

    Args:
        slope: (H, W, 2) surface slope (dh/dx along columns, dh/dy along rows), mm per mm.
        mm_per_px: pixel pitch, mm.

    Returns:
        (H, W) heightmap, mm, zero mean.
    """
    height_px, width_px = slope.shape[:2]
    # Height steps between neighbouring pixels, mm: (H, W-1) along x and (H-1, W) along y.
    step_x = 0.5 * (slope[:, 1:, 0] + slope[:, :-1, 0]) * mm_per_px
    step_y = 0.5 * (slope[1:, :, 1] + slope[:-1, :, 1]) * mm_per_px
    rhs = _difference_transpose(step_x, axis=1) + _difference_transpose(step_y, axis=0)
    eig_x = 4.0 * jnp.sin(jnp.pi * jnp.arange(width_px) / (2 * width_px)) ** 2
    eig_y = 4.0 * jnp.sin(jnp.pi * jnp.arange(height_px) / (2 * height_px)) ** 2
    eigenvalues = eig_y[:, None] + eig_x[None, :]
    coefficients = _cosine_transform(rhs)
    # The constant mode (eigenvalue 0) is the free offset: set it to zero.
    safe = jnp.where(eigenvalues > 0, eigenvalues, 1.0)
    coefficients = jnp.where(eigenvalues > 0, coefficients / safe, 0.0)
    return _cosine_transform(coefficients, inverse=True)


MATRIX_DCT_MAX_PX = 320
"""Largest image side whose cosine transforms are matrix products (beyond it, FFTs)."""


def _cosine_transform(x: Float[Array, "H W"], *, inverse: bool = False) -> Float[Array, "H W"]:
    """``dctn(x, type=2, norm="ortho")``, or ``idctn`` with ``inverse``."""
    if max(x.shape) > MATRIX_DCT_MAX_PX:
        return (idctn if inverse else dctn)(x, type=2, norm="ortho")
    rows = jnp.asarray(dct_matrix(x.shape[0]), x.dtype)
    cols = jnp.asarray(dct_matrix(x.shape[1]), x.dtype)
    return rows.T @ x @ cols if inverse else rows @ x @ cols.T


@functools.lru_cache(maxsize=16)
def dct_matrix(n: int) -> np.ndarray:
    """The orthonormal type-II DCT as an (n, n) float64 matrix: ``C @ x == dct(x, norm="ortho")``.

    ``C[k, j] = s_k cos(pi k (2j + 1) / 2n)`` with ``s_0 = sqrt(1/n)``, ``s_k = sqrt(2/n)``;
    orthogonal, so its transpose is the inverse transform. Read-only (cached).
    """
    k, j = np.arange(n)[:, None], np.arange(n)[None, :]
    matrix = np.sqrt(2.0 / n) * np.cos(np.pi * k * (2 * j + 1) / (2 * n))
    matrix[0] /= np.sqrt(2.0)
    matrix.setflags(write=False)
    return matrix


def zero_background(
    heightmap: Float[Array, "H W"], *, quantile: float = 0.1
) -> Float[Array, "H W"]:
    """Shift a heightmap known up to a constant so that its undeformed part sits at 0.

    The gel outside the contact is flat and undeformed; its height is estimated as the
    ``quantile`` of all pixels (robust to noise, correct while contact covers less than
    ``1 - quantile`` of the image). A contact that covers the whole gel uniformly leaves no
    slope at all and cannot be recovered from the image by any method. The quantile is
    ``jnp.quantile``'s, found by selection rather than a sort (:mod:`tactojax.shape._quantile`).

    Args:
        heightmap: (H, W) finite heightmap up to a constant, mm.
        quantile: fraction of pixels assumed undeformed, in (0, 1), static.

    Returns:
        (H, W) heightmap, mm.
    """
    return heightmap - exact_quantile(heightmap.ravel(), quantile)


def _difference_transpose(steps: Float[Array, "..."], axis: int) -> Float[Array, "..."]:
    """``D^T v`` for the forward difference ``D`` along ``axis`` (length n-1 -> n)."""
    pad = [(0, 0)] * steps.ndim
    pad[axis] = (1, 0)
    before = jnp.pad(steps, pad)  # v[j-1], with v[-1] = 0
    pad[axis] = (0, 1)
    after = jnp.pad(steps, pad)  # v[j], with v[n-1] = 0
    return before - after
