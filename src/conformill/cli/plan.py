"""`conformill plan` (being written)."""

from conformill.errors import ConformillError


def add_arguments(parser):
    pass


def run(args) -> int:
    raise ConformillError("plan is not implemented yet")
