"""``python -m puppet.cli``: the command line without the console script on PATH."""

from puppet.cli import main

main(prog_name="puppet")
