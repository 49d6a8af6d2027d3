"""`python -m photon_lightmaps ...`: see cli.py."""
import sys

from .cli import main

sys.exit(main())
