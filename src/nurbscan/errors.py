"""Errors that nurbscan reports to a user.

Every failure caused by input (a missing or corrupt file, a wrong size, a non-primitive
polynomial, no grid found, a diverging fit) raises :class:`NurbscanError` with one line that
names the input and the problem; the command line prints it and exits with status 2.
"""


class NurbscanError(Exception):
    """An error in the user's input, reported as one line naming the input and the problem."""
