"""The engines: B worlds stepped in one call, tick by tick (``world``: :class:`BatchedWorld`, its worlds split
over threads by ``chunks``) or from one decision event to the next (``events``: :class:`EventEngine`), and
the metrics of the episodes they play (``episode_stats``). Their numba kernels are ``catmip_env.kernels``."""
