"""Vocabulary shared by every stage of facestats.

* :mod:`~facestats.core.conventions`: names, units and codes (channels, face
  regions, conditions, skin types, sites);
* :mod:`~facestats.core.published`: numbers published in the papers (Weyrich et
  al. 2006 Tables 1-2, §7) that the synthetic population and the tests use;
* :mod:`~facestats.core.validate`: argument checks whose errors name the
  argument, its value and what was expected;
* :mod:`~facestats.core.blocked`: evaluation of element-wise kernels in
  cache-sized blocks.

Nothing here imports another part of facestats except :mod:`facestats.errors`.
"""
