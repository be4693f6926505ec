"""``python -m canal_client.cli``: the same as the ``canal`` command."""

from canal_client.cli.root import main

main()
