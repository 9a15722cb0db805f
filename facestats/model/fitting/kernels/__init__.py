"""Compiled (numba) kernels of the fit's hot loops: the ``"numba"`` engine of :mod:`facestats.model.fitting.engine`.

Each kernel does the per-sample work of one numpy function of the fit in a
single pass over every lumitexel's contiguous run of samples (see
:mod:`facestats.model.fitting.samples`), while the run sits in the CPU cache:

* :mod:`~facestats.model.fitting.kernels.samples` — the dome grid flattened into
  valid samples (:meth:`facestats.model.fitting.Samples.from_grid`, float16
  radiance converted on the way), the per-sample cosines and N·H, and the BRDF
  samples of eq. 8 (:func:`facestats.model.fitting.brdf_samples`);
* :mod:`~facestats.model.fitting.kernels.runs` — work over runs: photometric
  stereo (its samples, then per lumitexel the cameras' systems and all passes),
  micro-normals, the stable minimum of eq. 9, the refined albedo;
* :mod:`~facestats.model.fitting.kernels.factors` — the specular factors of the
  samples that enter eq. 14, on the full domain and one angle-limited one;
* :mod:`~facestats.model.fitting.kernels.lm` — the bounded Levenberg-Marquardt
  solve of eq. 14 (:mod:`facestats.model.fitting.solver`), texel by texel;
* :mod:`~facestats.model.fitting.kernels.fastexp` — the exponential of the
  lobes, written so that the compiler vectorises it.

Determinism: the kernels are compiled without ``fastmath``, so LLVM neither
reassociates sums nor contracts products into fused multiply-adds; every sum
runs in a fixed order (sample order, in float64), so the results are the
same bits on every CPU whatever vector width the compiler picks (checked by
``tests/model/fitting/test_engines.py``, which compiles them for a generic
x86-64 CPU and for the host).  Kernels are cached on disk (``cache=True``), so
a process compiles each once per facestats version.

This package imports numba; import it only when the numba engine is used.
"""
