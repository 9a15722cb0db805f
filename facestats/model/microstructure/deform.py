"""Deform a neutral microstructure map by the strain of a mesh frame (Nagano et al. 2015 §5).

The last step of the paper's method: at every texel the principal stretches
``r_s ≥ r_t`` and axes of the per-texel strain (eq. 11-13,
:class:`facestats.model.strain.TexelStrain`) select the kernels k^s, k^t from a
kernel table (eq. 8-9), and the neutral displacement map is convolved by the
two-pass filter (eq. 4-5) with σ converted to texels by the per-texel scale
(eq. 13's column norms), never across a UV-island border.  Texels no triangle
covers are copied.

The tangent-space normal map of the result is taken on the *deformed* surface:
with p the texel position, uv = M x0 on the rest surface (M = Q Rᵀ) and
x' = T x0 on the deformed one, the slope along the deformed tangent frame is
``∂h/∂x' = T⁻ᵀ Mᵀ diag(W, H) ∇_p h`` (heights µm, lengths mm → ×1e-3), the
``jacobian`` of :mod:`~facestats.model.microstructure.surface`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.errors import ValidationError
from facestats.model.microstructure.convolve import convolve_displacement
from facestats.model.microstructure.surface import tangent_normals
from facestats.model.microstructure.tables import kernel_parameters
from facestats.model.strain import inv2x2

__all__ = ["DeformedMicrostructure", "strain_kernels", "normal_jacobian", "deform_microstructure"]


@dataclass
class DeformedMicrostructure:
    """A deformed displacement map with its normals and the kernels that made it.

    Attributes
    ----------
    displacement : ndarray (H, W)
        Deformed heights D' (dtype of the neutral map).
    normals : ndarray (H, W, 3), float32
        Unit tangent-space normals of D' on the deformed surface; (0, 0, 1) off the mesh.
    alpha_s, sigma_s, alpha_t, sigma_t : ndarray (H, W), float32
        Kernel parameters per texel (σ in µm); α = 0 off the mesh.
    """

    displacement: np.ndarray
    normals: np.ndarray
    alpha_s: np.ndarray
    sigma_s: np.ndarray
    alpha_t: np.ndarray
    sigma_t: np.ndarray


def strain_kernels(strain, table="forehead"):
    """Per-texel (α_s, σ_s, α_t, σ_t) from a :class:`~facestats.model.strain.TexelStrain` (eq. 8-9), float32.

    Texels off the mesh (``valid`` False) get the identity kernel (α = 0).

    Parameters
    ----------
    strain : TexelStrain
        Per-texel principal stretches ``r_s ≥ r_t`` and ``valid`` mask, (H, W).
    table : str or KernelTable
        ``"forehead"`` (eq. 8-9, the default) or a table from
        :func:`facestats.model.microstructure.tables.fit_kernel_table`.

    Returns
    -------
    alpha_s, sigma_s, alpha_t, sigma_t : ndarray of float32, shape (H, W)
        α ∈ [−2, 1] and σ in µm along the s and t axes (r_t is taken as at least 1e-6).

    Raises
    ------
    ValidationError
        An unknown ``table``.
    """
    a_s, s_s = kernel_parameters(np.where(strain.valid, strain.r_s, 1.0), table)
    a_t, s_t = kernel_parameters(np.where(strain.valid, np.maximum(strain.r_t, 1e-6), 1.0), table)
    a_s, a_t = np.where(strain.valid, a_s, 0.0), np.where(strain.valid, a_t, 0.0)
    return tuple(x.astype(np.float32) for x in (a_s, s_s, a_t, s_t))


def normal_jacobian(strain, deformed=True) -> np.ndarray:
    """Per-texel map (H, W, 2, 2) from a texel gradient of heights in µm to tangent slopes (module docstring).

    ``deformed=False`` gives the rest surface's (T = I).

    Parameters
    ----------
    strain : TexelStrain
        The frame's per-texel T and M = Q Rᵀ, and the whole map's shape (W, H texels).
    deformed : bool
        Slopes along the deformed tangent frame (T⁻ᵀ Mᵀ diag(W, H) / 1000), else the rest one's.

    Returns
    -------
    ndarray of float64, shape (H, W, 2, 2)
        The ``jacobian`` of :func:`facestats.model.microstructure.surface.slopes` (per µm of height).
    """
    h, w = strain.map_shape
    m_t = np.swapaxes(strain.m, -1, -2)
    jac = m_t * np.array([w, h], float)[None, None, None, :] / 1000.0  # Mᵀ diag(W, H) / 1000
    if deformed:
        t_inv_t = np.swapaxes(inv2x2(strain.t)[0], -1, -2)
        # T⁻ᵀ J written out (column k of T⁻ᵀ times row k of J): numpy's matmul on millions of 2 × 2 stacks is slower
        jac = t_inv_t[..., :, 0, None] * jac[..., None, 0, :] + t_inv_t[..., :, 1, None] * jac[..., None, 1, :]
    return jac


def deform_microstructure(neutral, strain, table="forehead", *, backend="auto") -> DeformedMicrostructure:
    """Convolve a neutral displacement map according to a frame's per-texel strain (Nagano et al. 2015 §5).

    Parameters
    ----------
    neutral : ndarray (H, W), float32 or float64
        Neutral displacement map (µm) over the texels of ``strain`` (its window).
    strain : facestats.model.strain.TexelStrain
        Strain of the frame in those texels (:meth:`facestats.model.strain.MeshStrain.texels_strain`).
    table : str or KernelTable
        Kernel table (default the forehead table, eq. 8-9).
    backend : {"auto", "numba", "numpy"}

    Returns
    -------
    DeformedMicrostructure
    """
    d = np.asarray(neutral)
    if d.shape != strain.r_s.shape:
        raise ValidationError(f"neutral must cover the strain's texels, shape {strain.r_s.shape}, got shape {d.shape}")
    a_s, s_s, a_t, s_t = strain_kernels(strain, table)
    texel = np.stack(
        [np.where(strain.valid, strain.texel_um_s, 1.0), np.where(strain.valid, strain.texel_um_t, 1.0)], -1
    )
    out = convolve_displacement(
        d, strain.axis_s, a_s, s_s, a_t, s_t, texel, axis_t=strain.axis_t, islands=strain.island, backend=backend
    )
    normals = tangent_normals(out, normal_jacobian(strain))
    normals[~strain.valid] = (0.0, 0.0, 1.0)
    return DeformedMicrostructure(out, normals, a_s, s_s, a_t, s_t)
