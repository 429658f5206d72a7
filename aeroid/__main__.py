"""``python -m aeroid``: the ``aeroid`` command, for an environment whose scripts
folder is not on the PATH."""

from .cli import main

if __name__ == "__main__":
    main(prog_name="aeroid")
