"""The ``fixstream`` command line: one module per sub-command, imported lazily."""
