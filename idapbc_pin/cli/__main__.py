"""`python -m idapbc_pin.cli ...` runs the `idapbc-pin` command."""

import sys

from .main import main

sys.exit(main())
