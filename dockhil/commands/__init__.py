"""One module per `dockhil` subcommand; see dockhil/cli.py."""
