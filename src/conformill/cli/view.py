"""`conformill view` (being written)."""

from conformill.errors import ConformillError


def add_arguments(parser):
    pass


def run(args) -> int:
    raise ConformillError("view is not implemented yet")
