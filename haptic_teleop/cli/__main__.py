"""`python -m haptic_teleop.cli ...`: the `haptic-teleop` command."""

import sys

from haptic_teleop.cli.entry import main

sys.exit(main())
