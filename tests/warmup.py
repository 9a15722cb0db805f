"""Fill numba's on-disk kernel cache before the test workers start (see ``pytest_configure`` in conftest.py).

numba compiles a kernel on its first call and caches it beside the sources; on a fresh clone the test
workers and the processes they start (console scripts, notebook kernels, build workers) would otherwise
compile the same kernels at the same time.  Each function here runs the smallest work that compiles one
family of kernels; ``python -m tests.warmup microstructure`` runs one in a process of its own.
"""

import sys

import numpy as np


def fit_kernels():
    """The fit's kernels (about 24 CPU-s with an empty cache): one 8² subject simulated and fitted."""
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face
    from facestats.pipeline import fit_subject

    truth = synthesize_population(map_size=8, geometry=procedural_face(8), subjects=["S001"], conditions=False)["S001"]
    fit_subject(DomeSimulator(procedural_face(8)).simulate(truth))


def microstructure_kernels():
    """Nagano's convolution passes for float32 and float64 maps and the kernel fit's histogram (about 22 CPU-s)."""
    from facestats.model.microstructure import convolve_displacement, fit_kernel

    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        convolve_displacement(rng.normal(size=(24, 24)).astype(dtype), (0.6, 0.8), 0.5, 20.0, -0.5, 15.0, 10.0,
                              backend="numba")  # fmt: skip
    d = rng.normal(size=(80, 80))  # the smallest patch fit_kernel takes at 10 um/texel
    fit_kernel(d, d, (1.0, 0.0), 1.0, 10.0, alphas=np.array([0.0, 0.5]), sigmas_um=np.array([10.0, 20.0]),
               backend="numba")  # fmt: skip


if __name__ == "__main__":
    {"fit": fit_kernels, "microstructure": microstructure_kernels}[sys.argv[1]]()
