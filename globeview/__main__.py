"""`python -m globeview` is the `globeview` command."""

import sys

from globeview.cli import main

sys.exit(main())
