"""Dynamic skin microstructure: strain-driven displacement-map convolution (Nagano et al. 2015)."""
