"""``python -m sin3dm_lite.cli`` (and ``torchrun ... -m sin3dm_lite.cli``): the ``sin3dm-lite`` command."""

from . import main

raise SystemExit(main())
