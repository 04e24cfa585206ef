"""The ``face-tracking`` command line: one module per subcommand, registered in cli/main.py."""
