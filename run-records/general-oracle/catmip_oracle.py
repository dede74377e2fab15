"""``catmip`` with the privileged relay teacher of ``../relay-ceiling/relay.py`` registered under the
planner name ``rrt-relay-oracle``, so that ``--set anchor=rrt-relay-oracle`` works:

    python run-records/general-oracle/catmip_oracle.py train --preset general ... \\
        --set anchor=rrt-relay-oracle

The teacher reads the world's true state (which rescuers lack the news, and where they are now): it is
a training signal and a ceiling, not a baseline, so it is kept out of the package's planners."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "relay-ceiling"))
from relay import RelayOracle  # noqa: E402

from catmip_env import planners  # noqa: E402

planners.PLANNERS["rrt-relay-oracle"] = RelayOracle
from catmip_rl.cli.main import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
