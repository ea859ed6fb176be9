import sys

from sea_daemon.apps.cli import main

sys.exit(main())
