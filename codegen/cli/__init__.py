"""The command line (CLI.md): the verbs build, verify, plan, config, flash, stream and tune, on top of every stage."""
