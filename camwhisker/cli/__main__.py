"""``python -m camwhisker.cli``: the same as the ``camwhisker`` command."""

import sys

from camwhisker.cli.parser import main

sys.exit(main())
