"""The array kernels: the arithmetic of the per-frame path, one module per room.

A kernel is a plain, public function on float64 arrays of documented shapes and units. It checks nothing: the
public API of each room (``startracker.rotations``, ``startracker.track``, ...) validates its arguments once and then
calls the kernel; code that has already validated (the star tracker, the env) calls the kernel directly. Kernels
never draw random numbers: a stochastic step receives its draws from the caller's ``numpy.random.Generator``.
Where a kernel is on the per-frame hot path it is compiled with numba (``@njit(cache=True)``); the others are
vectorised numpy. ``docs/design.md`` ("Validation and kernels") says how to add one.
"""
