import os

os.environ.setdefault("MPLBACKEND", "Agg")
# pytest -n 2 runs two workers on a 2-core machine: one torch thread each avoids oversubscription
os.environ.setdefault("OMP_NUM_THREADS", "1")
