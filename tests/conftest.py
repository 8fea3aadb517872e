import os

# one BLAS thread: deterministic, and fast on the shared 2-core machines
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import tempfile  # noqa: E402

# the model cache of the app goes to a fresh folder per test session, never the user's ~/.cache/kexp
os.environ["KEXP_CACHE_DIR"] = tempfile.mkdtemp(prefix="kexp-cache-")
