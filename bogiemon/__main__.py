"""`python -m bogiemon`: the `bogiemon` command."""

import sys

from bogiemon.cli.main import main

sys.exit(main())
