"""``python -m drafttwin``: the command line (the ``drafttwin`` script's twin)."""

from drafttwin.cli import main

main()
