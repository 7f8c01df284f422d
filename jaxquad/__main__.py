"""`python -m jaxquad ...`: the `jaxquad` command."""

import sys

from jaxquad.cli import main

sys.exit(main())
