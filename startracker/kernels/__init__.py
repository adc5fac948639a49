"""Compiled numba kernels of startracker, one module per room."""
