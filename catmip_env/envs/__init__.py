"""The PettingZoo face: ``search_rescue_v0`` (the Parallel and AEC envs, ``from catmip_env import
search_rescue_v0``), its spaces, observations and infos (``spaces``) and its frames (``render``)."""
