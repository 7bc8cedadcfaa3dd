import os

# Keep numerical libraries to one thread each: the CI machine has 2 cores and tests run in one process.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
