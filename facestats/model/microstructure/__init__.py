"""Dynamic skin microstructure: strain-driven displacement-map convolution (Nagano et al. 2015).

Nagano, Fyffe, Alexander, Barbič, Li, Ghosh, Debevec 2015, *Skin Microstructure
Deformation with Displacement Map Convolution*, ACM TOG 34(4) 109.  When skin
stretches its microstructure blurs along the stretch, when it compresses it
sharpens; the paper models this as a spatially varying separable convolution of
a neutral displacement map with kernels looked up from the local stretch ratio.
Modules, one concept each:

* :mod:`~facestats.model.microstructure.kernel` — the kernel family k = (1 − α) δ + α G(σ) (eq. 6);
* :mod:`~facestats.model.microstructure.convolve` — the two-pass spatially varying convolution (eq. 1-5);
* :mod:`~facestats.model.microstructure.compiled` — its numba inner loops and their numpy twins;
* :mod:`~facestats.model.microstructure.tables` — kernel tables α(r), σ(r) (eq. 8-9) and their fit (Fig. 12);
* :mod:`~facestats.model.microstructure.surface` — slopes, tangent normals, normal histograms;
* :mod:`~facestats.model.microstructure.fit` — fitting (α, σ) to a patch pair (eq. 7, Fig. 11);
* :mod:`~facestats.model.microstructure.deform` — deforming a map by a mesh frame's strain (§5);
* :mod:`~facestats.model.microstructure.plots` — figures (Fig. 11/12, strain fields, histograms).

The strain itself (eq. 10-13) is :mod:`facestats.model.strain`.
"""

from facestats.model.microstructure.convolve import convolve_displacement
from facestats.model.microstructure.deform import DeformedMicrostructure, deform_microstructure
from facestats.model.microstructure.fit import KernelFit, fit_kernel
from facestats.model.microstructure.kernel import kernel_taps
from facestats.model.microstructure.surface import normal_histogram, tangent_normals
from facestats.model.microstructure.tables import FOREHEAD, KernelTable, fit_kernel_table, kernel_parameters

__all__ = [
    "kernel_parameters",
    "convolve_displacement",
    "fit_kernel",
    "KernelFit",
    "KernelTable",
    "FOREHEAD",
    "fit_kernel_table",
    "kernel_taps",
    "deform_microstructure",
    "DeformedMicrostructure",
    "tangent_normals",
    "normal_histogram",
]
