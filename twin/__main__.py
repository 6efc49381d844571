"""`python -m twin`: the `twin` command, as `python -m twin.cli` (what users try first)."""

import sys

from twin.cli import main

sys.exit(main())
