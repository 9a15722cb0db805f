"""Reflectance fields and relighting (Debevec et al. 2000), for measured and fitted faces."""
