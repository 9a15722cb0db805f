"""facestats: measure, analyse and edit the appearance of human facial skin.

The skin model is the one of Weyrich et al. 2006 (*Analysis of Human Faces using
a Measurement-Based Skin Reflectance Model*): a spatially varying Torrance-Sparrow
or Blinn-Phong specular BRDF, a diffuse albedo map and dipole subsurface
scattering.  Subpackages:

* :mod:`facestats.model` - the physics (Fresnel, BRDFs, dipole, skin model) and fitting;
* :mod:`facestats.acquire` - the dome and contact-sensor captures (devices or simulator);
* :mod:`facestats.io` - the Zarr parameter store and file formats;
* :mod:`facestats.pipeline` - the fit pipeline from captures to the store, and population builds;
* :mod:`facestats.analysis` - population statistics;
* :mod:`facestats.edit` - appearance editing;
* :mod:`facestats.relight` - reflectance fields and relighting (Debevec et al. 2000);
* :mod:`facestats.web` - the population statistics in a browser;
* :mod:`facestats.core` - vocabulary shared by every stage (conventions, validation, published values);
* :mod:`facestats.cli` - the ``facestats`` command line.

Heavy modules are imported lazily so the command line starts fast.
"""

from __future__ import annotations

from facestats.core.kernel_cache import refresh_kernel_caches
from facestats.core.version import __version__
from facestats.errors import FacestatsError

refresh_kernel_caches()  # numba's caches of changed kernels (and of their callers) must not be used

__all__ = ["FacestatsError", "__version__", "open_store"]


def open_store(path=None, mode="r"):
    """Open a facestats parameter store (``None``: the embedded default, read-only).

    See :func:`facestats.io.store.open_store`.
    """
    # local import: keeps numpy out of this module's import
    from facestats.io.store import open_store as _open_store

    return _open_store(path, mode=mode)
