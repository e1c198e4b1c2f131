"""``python -m wfjax``: the ``wfjax`` command (:func:`wfjax.cli.entry_point`)."""

from .cli import entry_point

if __name__ == "__main__":
    entry_point()
