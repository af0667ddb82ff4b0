import os

# Tiny LAPACK calls (LQR) are 10-20x slower with OpenBLAS's thread pool: keep tests on one thread.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
