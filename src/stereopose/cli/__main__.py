"""`python -m stereopose.cli`."""

import sys

from stereopose.cli import main

sys.exit(main())
