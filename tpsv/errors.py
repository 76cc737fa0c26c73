"""Exceptions that reach the user as one line on stderr and exit status 1."""


class TpsvError(Exception):
    """Bad input data or failed work; the message is shown to the user as is."""


class TpsvFormatError(TpsvError):
    """A .tpsv file that is truncated, corrupt, hostile or of an unknown version."""
