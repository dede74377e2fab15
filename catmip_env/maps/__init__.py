"""The map sets: the frozen digests of every evaluation's maps (``frozen_maps/``) and the check that an
evaluation plays the maps its seed names (``map_sets``). Maps are drawn by ``catmip_env.kernels.mapgen``;
hand-drawn layouts are ``catmip_env.ascii_maps``."""
