"""`python -m tests.export.lerobot_env`: build the LeRobot side environment (if not built) and print its
interpreter, for TWIN_LEROBOT_PYTHON or for reading exports with LeRobot by hand."""

import sys

from tests.export.lerobot_env import BuildError, lerobot_python

try:
    print(lerobot_python())
except BuildError as error:
    print(f"twin: error: {error}", file=sys.stderr)
    sys.exit(1)
