"""The bodies of the ``balance-opt`` commands, one module a group of commands; ``cli.py`` holds
the argument parser that calls them and the exit codes' handling."""
