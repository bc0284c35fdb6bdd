"""``python -m cpcc_client``: the same as the ``cpcc`` command."""

from cpcc_client.cli import main

raise SystemExit(main())
