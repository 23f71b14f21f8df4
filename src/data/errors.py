"""Errors of the data layer: each message names the file (and line) and the fix, so that a user
never has to read a numpy traceback to find out what is wrong with the data."""


class DataError(Exception):
    """A problem with the motion data or with how the data layer was configured."""
