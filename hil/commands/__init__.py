"""``hil`` subcommands, one module each, each with ``register(app)`` (see :mod:`hil.cli`)."""
