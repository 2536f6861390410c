"""`python -m voxax`: the `voxax` command."""

import sys

from .cli import main

sys.exit(main())
