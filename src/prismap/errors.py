"""The one documented error type for bad input.

Every reader, validator and command raises :class:`PrismapInputError` (a ``ValueError``) when its
input is wrong: a missing file, a field that does not parse, an array of the wrong shape or range.
The message names the file or argument, what was expected and what arrived. The CLI prints the
message without a traceback and exits with status 2.
"""


class PrismapInputError(ValueError):
    """Bad input: the message names the file or argument, the expectation and what arrived."""
