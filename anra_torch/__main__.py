"""``python -m anra_torch``: the ``anra`` command line."""

from anra_torch.cli import main

raise SystemExit(main())
