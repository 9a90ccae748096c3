"""The process, not the maths: forked helpers, the parallel engine (dask), the command's
budget of memory and time, and the compiled kernels' cache.

Library layers below the CLI call into this package; it imports nothing of the layers above it.
"""
