"""Command line: one module per subcommand; the only place errors become exit codes."""
