"""``python -m catmip_rl.cli ...`` is ``catmip ...``."""

import sys

from catmip_rl.cli.main import main

sys.exit(main())
