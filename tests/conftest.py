import os

# one BLAS thread: deterministic, and fast on the shared 2-core machines
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
