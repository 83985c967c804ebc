"""``python -m cli ARGS`` runs ``rig ARGS``."""

from cli.main import main

main()
