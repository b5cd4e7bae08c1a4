"""``python -m skelfuse``: the same command line as the ``skelfuse`` console script."""

from skelfuse.cli import entrypoint

if __name__ == "__main__":
    entrypoint()
